"""Configuration: YAML files under ``configs/``, profiles, and where things are stored.

Option values are resolved in this order, later ones winning:

1. the plugin's own defaults (its ``Options`` dataclass);
2. ``configs/methods/<name>.yaml`` or ``configs/datasets/<name>.yaml``;
3. the profile (``configs/profiles/<profile>.yaml``: ``quick`` for a CPU, ``standard`` for
   issue 27's training scale, ``paper`` for the paper's scale), under its
   ``methods:``/``datasets:``/``trainer:`` keys (a profile may ``extends: <other>`` and state
   only what differs);
4. the sweep file's per-entry options (``shapebench sweep``);
5. command-line flags (``-O key=value`` for the method, ``-D key=value`` for the dataset).

``configs/`` is looked up in ``$SHAPEBENCH_CONFIG_DIR``, then ``./configs`` (``shapebench init``
writes an editable copy there), then the source checkout of an editable install, then the copy
every wheel carries (``shapebench/_configs``, made from the checkout's ``configs/`` at build
time: setup.py). A file found earlier wins, one file at a time.
"""

from __future__ import annotations

import difflib
import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from shapebench.api.errors import ConfigError, UnknownNameError

#: The profile of a command that names none and runs without $SHAPEBENCH_PROFILE: issue 27's
#: training scale, whose reference weights ship (``quick`` stays one flag away).
DEFAULT_PROFILE = "standard"
WORKSPACE_DIRNAME = "shapebench-runs"


def builtin_config_dir() -> Path | None:
    """The configs shapebench was installed with: the checkout's ``configs/`` for an editable
    install (a folder beside the package with a pyproject.toml), else the wheel's package data."""
    checkout = Path(__file__).resolve().parents[1]
    if (checkout / "pyproject.toml").is_file() and (checkout / "configs").is_dir():
        return checkout / "configs"
    packaged = Path(str(resources.files("shapebench") / "_configs"))
    return packaged if packaged.is_dir() else None


def config_dirs() -> list[Path]:
    dirs = []
    if os.environ.get("SHAPEBENCH_CONFIG_DIR"):
        dirs.append(Path(os.environ["SHAPEBENCH_CONFIG_DIR"]))
    dirs.append(Path.cwd() / "configs")
    if (builtin := builtin_config_dir()) is not None:
        dirs.append(builtin)
    seen, out = set(), []
    for d in dirs:
        if d.is_dir() and d.resolve() not in seen:
            seen.add(d.resolve())
            out.append(d)
    return out


def sweep_names() -> list[str]:
    """The sweeps that run by name: every ``sweeps/NAME.yaml`` of :func:`config_dirs`."""
    return sorted({f.stem for d in config_dirs() for f in (d / "sweeps").glob("*.yaml")})


def find_sweep(given: str | Path) -> Path:
    """The sweep file ``given`` names: a path to a file, or the name of a sweep in
    :func:`config_dirs` (``default`` is ``configs/sweeps/default.yaml``, the user's own first,
    then the built-in one), so that ``shapebench sweep default`` runs from any folder."""
    path = Path(given)
    if path.is_file():
        return path
    name = str(given)
    if not path.suffix and len(path.parts) == 1:
        for d in config_dirs():
            if (d / "sweeps" / f"{name}.yaml").is_file():
                return d / "sweeps" / f"{name}.yaml"
    names = sweep_names()
    hint = (
        f"the built-in sweeps: {', '.join(names) or 'none'}; 'shapebench init' writes an "
        "editable copy of the default one into ./configs/sweeps/"
    )
    if path.suffix or len(path.parts) > 1:
        raise ConfigError(f"sweep file not found: {path}", hint)
    close = difflib.get_close_matches(name, names, n=1)
    raise ConfigError(
        f"no sweep file or built-in sweep named {name!r}"
        + (f" (did you mean {close[0]!r}?)" if close else ""),
        hint,
    )


#: What ``shapebench init`` copies: every profile and the example sweep, relative to a config dir.
INIT_FILES = ("profiles/*.yaml", "sweeps/default.yaml")


def write_editable_configs(dest: Path, overwrite: bool = False) -> tuple[list[Path], list[Path]]:
    """Copy the built-in profiles and example sweep into ``dest/configs``; the (written, kept)
    paths. A file already there is kept unless ``overwrite``: it may hold the user's edits."""
    source = builtin_config_dir()
    if source is None:
        raise ConfigError(
            "this shapebench installation carries no built-in configs",
            hint="reinstall it from a wheel or a checkout (pip install shapebench)",
        )
    written: list[Path] = []
    kept: list[Path] = []
    for pattern in INIT_FILES:
        for src in sorted(source.glob(pattern)):
            target = Path(dest) / "configs" / src.relative_to(source)
            if target.exists() and not overwrite:
                kept.append(target)
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(src.read_bytes())
            written.append(target)
    return written, kept


def read_yaml(path: Path) -> dict[str, Any]:
    # Imported here: the CLI imports this module for DEFAULT_PROFILE while building its --help,
    # and PyYAML is most of this module's import time.
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text()) or {}
    except FileNotFoundError as exc:
        raise ConfigError(f"config file not found: {path}") from exc
    except yaml.YAMLError as exc:
        # One line naming the place: the parser's own message spans several lines and names a
        # "<unicode string>" instead of the file.
        mark = getattr(exc, "problem_mark", None)
        where = f", line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"config file {path}{where} is not valid YAML: {problem}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path} must hold a mapping at the top level")
    return data


def _find(kind: str, name: str) -> Path | None:
    for d in config_dirs():
        path = d / kind / f"{name}.yaml"
        if path.exists():
            return path
    return None


def available_profiles() -> list[str]:
    return sorted({p.stem for d in config_dirs() for p in (d / "profiles").glob("*.yaml")})


def load_profile(name: str, _seen: tuple[str, ...] = ()) -> dict[str, Any]:
    """The profile ``name``; one that says ``extends: <other>`` is that profile with its own keys
    merged in (mappings key by key, anything else replaced), so a profile that changes a few
    budgets states only those and cannot drift from the profile it extends."""
    path = _find("profiles", name)
    if path is None:
        raise UnknownNameError(
            "profile",
            name,
            available_profiles(),
            hint="profiles live in configs/profiles/<name>.yaml; 'shapebench init' writes "
            "an editable copy of the built-in ones, or set SHAPEBENCH_CONFIG_DIR to use yours",
        )
    data = read_yaml(path)
    parent = data.pop("extends", None)
    if parent is None:
        return data
    if not isinstance(parent, str):
        raise ConfigError(f"profile {path}: 'extends' must name one profile, got {parent!r}")
    if parent in (*_seen, name):
        chain = " -> ".join((*_seen, name, parent))
        raise ConfigError(f"profile {path}: 'extends' goes round in a circle ({chain})")
    return _merged(load_profile(parent, (*_seen, name)), data)


def _merged(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merged(out[key], value)
        else:
            out[key] = value
    return out


def plugin_overrides(kind: str, name: str, profile: dict[str, Any]) -> dict[str, Any]:
    """Options for method/dataset ``name`` from its config file and the profile."""
    values: dict[str, Any] = {}
    path = _find(f"{kind}s", name)
    if path is not None:
        values.update(read_yaml(path).get("options", {}) or {})
    values.update((profile.get(f"{kind}s") or {}).get(name, {}) or {})
    return values


@dataclass(frozen=True)
class Settings:
    """Where runs, artifacts and cached data go."""

    tracking_uri: str
    artifact_root: Path
    cache_dir: Path
    profile_name: str
    profile: dict[str, Any]

    @property
    def workspace(self) -> Path:
        """The workspace folder: the embedded store, artifacts, checkpoints, logs, tables."""
        return self.artifact_root.parent

    @property
    def is_remote(self) -> bool:
        return self.tracking_uri.startswith(("http://", "https://"))


def default_cache_dir() -> Path:
    if os.environ.get("SHAPEBENCH_CACHE_DIR"):
        return Path(os.environ["SHAPEBENCH_CACHE_DIR"])
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "shapebench"


def default_profile() -> str:
    """The profile in effect when a command names none: ``$SHAPEBENCH_PROFILE``, else
    :data:`DEFAULT_PROFILE`. A row's label names its profile only when it is another one."""
    return os.environ.get("SHAPEBENCH_PROFILE") or DEFAULT_PROFILE


def make_settings(
    tracking_uri: str | None = None,
    cache_dir: str | Path | None = None,
    profile: str | None = None,
    workspace: str | Path | None = None,
) -> Settings:
    ws = Path(workspace or os.environ.get("SHAPEBENCH_WORKSPACE") or WORKSPACE_DIRNAME).absolute()
    uri = tracking_uri or os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{ws / 'mlflow.db'}"
    profile_name = profile or default_profile()
    return Settings(
        tracking_uri=uri,
        artifact_root=ws / "artifacts",
        cache_dir=Path(cache_dir) if cache_dir else default_cache_dir(),
        profile_name=profile_name,
        profile=load_profile(profile_name),
    )
