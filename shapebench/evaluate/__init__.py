"""Evaluating a method: ``shapebench run`` end to end (:mod:`~shapebench.evaluate.orchestrate`),
one method on one dataset cell by cell (:mod:`~shapebench.evaluate.runner`), completion pictures
(:mod:`~shapebench.evaluate.pictures`) and preprocessing ahead of a run
(:mod:`~shapebench.evaluate.prepare`). Cell records are handed to :mod:`shapebench.store`.
"""
