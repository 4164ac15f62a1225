"""Evaluating a method: ``shapebench run`` end to end (:mod:`~shapebench.evaluation.orchestrate`),
one method on one dataset cell by cell (:mod:`~shapebench.evaluation.runner`), completion pictures
(:mod:`~shapebench.evaluation.pictures`) and preprocessing ahead of a run
(:mod:`~shapebench.evaluation.prepare`). Cell records are handed to :mod:`shapebench.store`.
"""
