"""The record of every run, and the only code that imports :mod:`mlflow` or names a tag.

:mod:`~shapebench.store.records` defines every tag, param and run kind;
:mod:`~shapebench.store.tracking` opens the store and keeps the cell ledger;
:mod:`~shapebench.store.presentation` lays cells and sweeps out for the MLflow UI;
:mod:`~shapebench.store.listing`, :mod:`~shapebench.store.merge` and :mod:`~shapebench.store.ui`
serve ``shapebench runs/show``, ``merge`` and ``ui``, with the UI's links from
:mod:`~shapebench.store.urls`; :mod:`~shapebench.store.locks` and
:mod:`~shapebench.store.provenance` (code version, process and machine tags) are what the records
rely on.
"""
