"""PoinTr (Yu et al., ICCV 2021): point proxies, a geometry-aware transformer and a folding head."""
