"""The plugin contract: everything a method, dataset or metric plugin implements or receives.

* :mod:`~shapebench.api.method`, :mod:`~shapebench.api.dataset`, :mod:`~shapebench.api.metric`:
  the three interfaces;
* :mod:`~shapebench.api.types`: the plain data passed between them;
* :mod:`~shapebench.api.options`: a dataclass of options per plugin;
* :mod:`~shapebench.api.hookspecs`: the pluggy hooks a plugin implements;
* :mod:`~shapebench.api.protocol`: what a method sees at test time, and the frame of distances;
* :mod:`~shapebench.api.contexts`: the context points every method is given;
* :mod:`~shapebench.api.errors`: errors a user can act on.

This room imports only :mod:`shapebench.geometry`, :mod:`shapebench.preprocess` and the
top-level utilities (:mod:`shapebench.hashing`); the most used names are re-exported by
:mod:`shapebench` itself. Nothing is imported here, so ``import shapebench.api`` stays cheap.
"""
