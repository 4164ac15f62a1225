"""The checks of ``shapebench check`` as assertions, for a plugin's own test suite.

::

    from shapebench.conformance.testing import check_method, check_metric

    def test_my_method_follows_the_rules():
        check_method("my-method", epochs=2)   # a registered name, with option overrides

    def test_my_metric_follows_the_rules():
        check_metric(MyMetric)                # or the class itself, registered or not

Each helper runs every check of :mod:`shapebench.conformance` on the component and raises
:class:`PluginCheckFailed` (an ``AssertionError``, so pytest shows it as a failed assertion)
listing each failed check with its reason; skipped checks do not fail. It returns the
:class:`~shapebench.conformance.framework.ComponentReport` otherwise.

The checks build a tiny synthetic dataset in a temporary folder; to build it once per test
session, add ``pytest_plugins = ["shapebench.conformance.testing"]`` to your ``conftest.py`` and
pass the ``shapebench_check_env`` fixture as ``env=``.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from shapebench.conformance.framework import CheckEnv, Component, ComponentReport
from shapebench.conformance.runner import (
    check_component,
    class_component,
    component,
    distribution_components,
)


class PluginCheckFailed(AssertionError):
    """A component failed checks; the message lists each with its reason."""

    def __init__(self, reports: list[ComponentReport]) -> None:
        self.reports = reports
        lines = []
        for rep in reports:
            failed = rep.failures
            if not failed:
                continue
            lines.append(f"{rep.component.title} failed {len(failed)} check(s):")
            for res in failed:
                lines.append(f"  {res.check}: {res.reason}")
                if res.traceback:  # an unexpected exception: where it came from
                    lines += ["    " + ln for ln in res.traceback.rstrip().splitlines()[-6:]]
        super().__init__("\n".join(lines))


def check_method(
    method: str | type, *, env: CheckEnv | None = None, **options: Any
) -> ComponentReport:
    """Check a method (registered name or class); ``options`` override its check options."""
    return _check_one("method", method, env, options)


def check_dataset(
    dataset: str | type,
    *,
    data_root: str | Path | None = None,
    env: CheckEnv | None = None,
    **options: Any,
) -> ComponentReport:
    """Check a dataset (registered name or class); ``data_root`` is the local copy it reads."""
    return _check_one("dataset", dataset, env, options, data_root)


def check_metric(metric: str | type, *, env: CheckEnv | None = None) -> ComponentReport:
    """Check a metric (registered name or class): its card and its values."""
    return _check_one("metric", metric, env, {})


def check_distribution(
    distribution: str, *, data_root: str | Path | None = None, env: CheckEnv | None = None
) -> list[ComponentReport]:
    """Check every method, dataset and metric an installed distribution registers."""
    with _env(env) as e:
        comps = distribution_components(e.registry, distribution)
        return _passed([check_component(c, e, None, data_root) for c in comps])


def assert_passed(reports: ComponentReport | list[ComponentReport]) -> None:
    """Raise :class:`PluginCheckFailed` if any check of ``reports`` failed."""
    _passed(reports if isinstance(reports, list) else [reports])


def _check_one(
    kind: str,
    target: str | type,
    env: CheckEnv | None,
    options: dict[str, Any],
    data_root: str | Path | None = None,
) -> ComponentReport:
    with _env(env) as e:
        comp: Component
        if isinstance(target, str):
            comp = component(e.registry, kind, target)
        else:
            comp = class_component(kind, target)
        return _passed([check_component(comp, e, options, data_root)])[0]


def _passed(reports: list[ComponentReport]) -> list[ComponentReport]:
    if any(rep.failures for rep in reports):
        raise PluginCheckFailed(reports)
    return reports


@contextmanager
def _env(env: CheckEnv | None) -> Iterator[CheckEnv]:
    if env is not None:
        yield env
        return
    with CheckEnv() as own:
        yield own


try:  # the helpers work without pytest; only the fixture needs it
    import pytest
except ImportError:  # pragma: no cover
    pytest = None  # type: ignore[assignment]

if pytest is not None:

    @pytest.fixture(scope="session")
    def shapebench_check_env(tmp_path_factory: Any) -> Iterator[CheckEnv]:
        """One :class:`~shapebench.conformance.framework.CheckEnv` per test session: the tiny
        dataset the checks use is built once (enable with
        ``pytest_plugins = ["shapebench.conformance.testing"]``)."""
        with CheckEnv(workdir=tmp_path_factory.mktemp("shapebench-check")) as env:
            yield env
