"""Geometry helpers: nearest neighbours, surface sampling, point-cloud files."""
