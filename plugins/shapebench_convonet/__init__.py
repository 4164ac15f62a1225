"""ConvONet (Peng et al., ECCV 2020): convolutional occupancy networks, a local implicit method."""
