"""From names and overrides to configured method, dataset and metric instances."""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from shapebench.api import options as opts
from shapebench.api.dataset import Dataset
from shapebench.api.errors import ConfigError, DataNotFoundError
from shapebench.api.method import Method
from shapebench.api.metric import PRESETS, Metric
from shapebench.config import Settings, plugin_overrides
from shapebench.registry.discovery import Registration, Registry


@dataclass
class ResolvedMethod:
    registration: Registration
    cls: type[Method]
    options: Any
    #: The options before the run's own overrides (plugin defaults, config file, profile):
    #: what a leaderboard row's label is relative to.
    base_options: Any = None

    @property
    def name(self) -> str:
        return self.registration.name

    @property
    def display_name(self) -> str:
        return self.cls.display_name or self.name

    def code(self) -> str:
        """Digest of the source the method's results depend on (see
        shapebench.registry.code_digest)."""
        return self._code

    @functools.cached_property
    def _code(self) -> str:  # computed once: config() runs for every cell of a run
        from shapebench.registry.code_digest import code_digest

        return code_digest(self.cls)

    @functools.cached_property
    def _completion_code(self) -> str:
        from shapebench.registry.code_digest import completion_digest

        return completion_digest(self.cls)

    def effective_options(self) -> Any:
        """The options as the method instance holds them: values a method fills in itself
        (recipe-dependent ``None`` options) are resolved, so params and keys show what ran."""
        return self._effective

    @functools.cached_property
    def _effective(self) -> Any:  # one instance, not one per cell
        return getattr(self.instantiate(), "options", self.options)

    def config(self) -> dict[str, Any]:
        """What determines a cell's completions: the training's inputs and the completion code
        (``completion_code``, only for a method that names ``completion_modules``)."""
        plugin = self.registration.plugin
        cfg = {
            "name": self.name,
            "options": opts.as_dict(self.effective_options()),
            "distribution": plugin.distribution,
            "version": plugin.version,
            "code": self.code(),
        }
        if self._completion_code:
            cfg["completion_code"] = self._completion_code
        return cfg

    def overrides(self) -> dict[str, Any]:
        """The options this run sets differently from the profile's defaults."""
        if self.base_options is None:
            return {}
        base, final = opts.as_dict(self.base_options), opts.as_dict(self.options)
        return {k: v for k, v in final.items() if base.get(k) != v}

    def with_options(self, **changes: Any) -> ResolvedMethod:
        from dataclasses import replace

        return ResolvedMethod(
            self.registration, self.cls, replace(self.options, **changes), self.base_options
        )

    def training_config(self) -> dict[str, Any]:
        """What determines a training's result: options that only affect completion are left out."""
        effective = self.effective_options()
        opts_dict = {
            f.name: getattr(effective, f.name)
            for f in fields(effective)
            if not f.metadata.get("completion_only")
        }
        plugin = self.registration.plugin
        return {
            "family": self.cls.checkpoint_family or self.name,
            "options": opts_dict,
            "distribution": plugin.distribution,
            "version": plugin.version,
            "code": self.code(),
        }

    def instantiate(self) -> Method:
        return self.cls(self.options)


def resolve_method(
    registry: Registry, name: str, settings: Settings, *overrides: dict[str, Any]
) -> ResolvedMethod:
    reg = registry.get("method", name)
    cls = reg.load()
    values = plugin_overrides("method", name, settings.profile)
    base = opts.build(cls.Options, values, f"method {name!r}")
    budgets = {f.name for f in fields(cls.Options)} >= {"epochs", "steps"}
    for o in overrides:
        o = o or {}
        values.update(o)
        if budgets and "epochs" in o and "steps" not in o:
            # An epoch budget given over a step budget (the quick profile's) replaces it, as
            # --max-epochs does: -O epochs=5 trains 5 epochs, not the profile's 2700 steps.
            values["steps"] = 0
    return ResolvedMethod(reg, cls, opts.build(cls.Options, values, f"method {name!r}"), base)


def resolve_dataset(
    registry: Registry,
    name: str,
    settings: Settings,
    data_root: str | Path | None,
    *overrides: dict[str, Any],
) -> Dataset:
    reg = registry.get("dataset", name)
    cls = reg.load()
    values = plugin_overrides("dataset", name, settings.profile)
    for o in overrides:
        values.update(o or {})
    options = opts.build(cls.Options, values, f"dataset {name!r}")
    root = data_root or os.environ.get(f"SHAPEBENCH_{name.upper().replace('-', '_')}_ROOT")
    if cls.needs_data_root:
        hint = (
            getattr(cls, "obtain_hint", None) or f"pass --data-root pointing to your copy of {name}"
        )
        if not root:
            raise DataNotFoundError(
                f"dataset {name!r} reads a local copy, and none was given", hint
            )
        if not Path(root).exists():
            raise DataNotFoundError(f"data root {root} for dataset {name!r} does not exist", hint)
    elif root and not Path(root).exists():
        raise DataNotFoundError(f"data root {root} does not exist")
    dataset = cls(options, settings.cache_dir, Path(root) if root else None)
    return dataset


def expand_presets(names: list[str], installed: list[str]) -> list[str]:
    """``names`` with every preset (:data:`shapebench.api.metric.PRESETS`) replaced by its
    metrics (installed names win over presets), each metric once, in order."""
    out: list[str] = []
    for name in names:
        for metric in (name,) if name in installed else PRESETS.get(name, (name,)):
            if metric not in out:
                out.append(metric)
    return out


def resolve_metrics(
    registry: Registry, names: list[str] | None, dataset: Dataset | None = None
) -> list[Metric]:
    """The metrics ``names`` (``--metric``), or every installed metric computed by default
    (:attr:`Metric.by_default`) when none is named. On a dataset without ground truth only
    metrics that need none apply: named ones that need it are refused, and the default is
    every metric that needs none."""
    ground_truth = dataset is None or dataset.has_ground_truth
    if names:
        names = expand_presets(list(names), registry.names("metric"))
        classes = [registry.load("metric", n) for n in names]
        if not ground_truth:
            refused = [n for n, c in zip(names, classes, strict=True) if _needs_truth(c)]
            if refused:
                usable = [
                    n
                    for n in registry.names("metric")
                    if not _needs_truth(registry.load("metric", n))
                ]
                raise ConfigError(
                    f"metric {', '.join(refused)} does not apply to dataset {dataset.name!r}: "
                    "it has no ground truth",
                    f"metrics that compare with the input apply: {', '.join(usable) or 'none'}",
                )
        return [cls() for cls in classes]
    classes = [registry.load("metric", n) for n in registry.names("metric")]
    if ground_truth:
        metrics = [cls() for cls in classes if getattr(cls, "by_default", True)]
    else:
        metrics = [cls() for cls in classes if not _needs_truth(cls)]
    if not metrics:
        raise ConfigError("no metric is installed", "reinstall shapebench: it provides chamfer-l2")
    return metrics


def _needs_truth(cls: type) -> bool:
    return bool(getattr(cls, "needs_ground_truth", True))
