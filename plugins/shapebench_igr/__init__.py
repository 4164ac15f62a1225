"""IGR (Gropp et al., 2020) as a shapebench method plugin."""
