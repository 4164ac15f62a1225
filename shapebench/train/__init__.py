"""Training trainable methods: what identifies one training, its key and where its weights come
from (:mod:`~shapebench.train.ticket`), one process per training
(:mod:`~shapebench.train.training`), the PyTorch Lightning loop
(:mod:`~shapebench.train.lightning_fit`) with its training data (:mod:`~shapebench.train.data`),
seeding (:mod:`~shapebench.train.seeding`), callbacks (:mod:`~shapebench.train.callbacks`) and
summary (:mod:`~shapebench.train.summary`), the base class of every Lightning-trained method
(:mod:`~shapebench.train.lightning_method`), safe checkpoint loading and resuming
(:mod:`~shapebench.train.checkpoints`) and the reference checkpoints shipped with shapebench
(:mod:`~shapebench.train.references`).
"""
