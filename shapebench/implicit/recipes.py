"""Paper or official hyper-parameters, one option apart.

Where the paper and the official code disagree (see the docs of each method), an option left at
``None`` takes its value from the method's recipe: ``recipe="paper"`` (the default: the benchmark
reproduces the paper's protocol) or ``recipe="official"``. An explicit value always wins.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from shapebench.errors import ConfigError


def apply_recipe(options: Any, recipes: dict[str, dict[str, Any]], owner: str) -> Any:
    recipe = options.recipe
    if recipe not in recipes:
        raise ConfigError(f"{owner}: unknown recipe {recipe!r}; use one of {sorted(recipes)}")
    values = {k: v for k, v in recipes[recipe].items() if getattr(options, k) is None}
    return dataclasses.replace(options, **values)
