"""Evaluating a method: ``shapebench run`` end to end (:mod:`~shapebench.evaluation.orchestrate`),
one method on one dataset cell by cell (:mod:`~shapebench.evaluation.runner`, with what a cell is
and its key in :mod:`~shapebench.evaluation.plan`, the objects it loads in
:mod:`~shapebench.evaluation.objects`, completing in :mod:`~shapebench.evaluation.completion`,
scoring in :mod:`~shapebench.evaluation.scoring`, the failure reasons in
:mod:`~shapebench.evaluation.failures`, the files it logs in :mod:`~shapebench.evaluation.artifacts`
and what it hands back in :mod:`~shapebench.evaluation.results`), completion pictures
(:mod:`~shapebench.evaluation.pictures`) and preprocessing ahead of a run
(:mod:`~shapebench.evaluation.prepare`). Cell records are handed to :mod:`shapebench.store`.
"""
