"""Training trainable methods: one process per training (:mod:`~shapebench.train.training`),
the PyTorch Lightning loop (:mod:`~shapebench.train.lightning_fit`), the base class of every
Lightning-trained method (:mod:`~shapebench.train.lightning_method`), safe checkpoint loading
(:mod:`~shapebench.train.checkpoints`) and the reference checkpoints shipped with shapebench
(:mod:`~shapebench.train.references`).
"""
