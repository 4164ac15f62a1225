"""PCN, the Point Completion Network (Yuan et al., 2018), as a shapebench method plugin."""
