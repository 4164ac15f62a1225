"""Occupancy Networks (Mescheder et al., 2019) as a shapebench method plugin."""
