"""MSC, Bayesian meta-learning shape completion (the paper this benchmark reproduces)."""
