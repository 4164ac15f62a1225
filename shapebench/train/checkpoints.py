"""Loading checkpoints safely, and telling damaged files apart from good ones.

A checkpoint may come from the user (``--checkpoint PATH``), so it is read with
``torch.load(..., weights_only=True)``: tensors, plain containers and numbers only, never an
arbitrary Python object whose unpickling could run code. Every module's hyper-parameters are
plain values (``save_hyperparameters()`` of int, float, str and list arguments), so a checkpoint
written by ``shapebench train`` always passes.

PyTorch checkpoints are zip archives whose members carry a CRC-32, but ``torch.load`` does not
check it: a flipped bit in a weight loads silently. :func:`load_safely` checks every member's
CRC first, so a truncated or corrupted file is reported (one line naming it) instead of giving
wrong completions.

A checkpoint trained by shapebench carries its checkpoint key (``fit_lightning`` writes it into
the checkpoint as ``checkpoint["shapebench"]["key"]``; older ones have it in ``done.json`` beside
them): :func:`verify_checkpoint` refuses one trained for another configuration.

A training resumes from ``last.ckpt`` (:data:`LAST`) in its private folder:
:func:`resume_state` reads it once (a damaged one is deleted, one of another key refused),
:func:`checkpoint_epochs` and :func:`describe_progress` say how far one got, and
:func:`kept_message` what an interrupted training leaves to resume from.

Damaged cache files (preprocessed arrays, context orders) are reported with
:func:`warn_corrupt` and rebuilt by their owners.

torch and Lightning are imported inside the functions: :mod:`shapebench.train.training` imports this
module, and the command line keeps heavy imports out of ``shapebench --help``.
"""

from __future__ import annotations

import inspect
import io
import json
import re
import zipfile
from pathlib import Path
from typing import Any

from shapebench.api.errors import (  # noqa: F401 (CorruptFileWarning, describe: imported from here too)
    CorruptFileWarning,
    ShapebenchError,
    describe,
    warn_corrupt,
)

#: Where a checkpoint written by shapebench keeps what shapebench needs to know about it.
STAMP = "shapebench"

#: The file :func:`shapebench.train.training.train_here` writes beside a finished checkpoint.
DONE_FILE = "done.json"

#: The checkpoint a training resumes from, in its private folder.
LAST = "last.ckpt"

_ZIP_MAGIC = b"PK\x03\x04"


def _retrain_hint(path: Path) -> str:
    """How to replace a bad checkpoint: retrain one of shapebench's own (its folder holds
    ``done.json``), copy a user's file again (never suggest deleting a user's folder)."""
    if (path.parent / DONE_FILE).exists():
        return f"delete {path.parent} and rerun: shapebench trains it again"
    return "copy or download the file again, or retrain it with 'shapebench train'"


def _damaged(path: Path, reason: str, zipped: bool = True) -> ShapebenchError:
    what = "is damaged" if zipped else "is damaged or not a PyTorch checkpoint"
    return ShapebenchError(f"checkpoint {path} {what} ({reason})", _retrain_hint(path))


def _refused(path: Path, reason: str) -> ShapebenchError:
    return ShapebenchError(
        f"checkpoint {path} holds Python objects besides weights and hyper-parameters "
        f"({reason}); shapebench does not load it, since unpickling them could run any code",
        "pass a checkpoint written by 'shapebench train' (state dict and plain hyper-parameters)",
    )


def _check_zip(path: Path, data: bytes) -> None:
    """Raise if the zip archive ``data`` is truncated or a member's CRC-32 does not match."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            bad = archive.testzip()  # reads every member and checks its CRC-32
    except Exception as exc:  # BadZipFile when truncated, zlib/struct errors when garbled
        raise _damaged(path, describe(exc)) from None
    if bad is not None:
        raise _damaged(path, f"checksum mismatch in {bad}")


def load_safely(path: Path, map_location: Any = "cpu") -> dict[str, Any]:
    """The checkpoint dict at ``path``, read with ``weights_only=True`` after a checksum test.

    Raises :class:`ShapebenchError` (one line naming the file) when the file is missing,
    truncated or corrupted, not a PyTorch checkpoint, or holds pickled objects other than
    tensors and plain values (those are refused, never executed).
    """
    import pickle

    import torch

    path = Path(path)
    try:
        data = path.read_bytes()  # read once: a file replaced meanwhile cannot mix two versions
    except FileNotFoundError:
        raise ShapebenchError(f"checkpoint {path} does not exist") from None
    except OSError as exc:
        raise ShapebenchError(f"cannot read checkpoint {path}: {describe(exc)}") from None
    if not data:
        raise _damaged(path, "empty file")
    zipped = data.startswith(_ZIP_MAGIC)  # torch's format since 1.6; older ones have no CRCs
    if zipped:
        _check_zip(path, data)
    try:
        checkpoint = torch.load(io.BytesIO(data), map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as exc:
        # torch names the global it refused ("... unsupported GLOBAL posix.system ..."); any
        # other unpickling error (an unknown opcode) means garbled bytes.
        refused = re.search(r"GLOBAL (\S+)", str(exc))
        if refused:
            raise _refused(path, f"it pickles {refused.group(1)}") from None
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip().startswith("Unsupported")]
        reason = f"garbled data: {lines[0]}" if lines else describe(exc)
        raise _damaged(path, reason, zipped) from None
    except Exception as exc:  # EOFError, RuntimeError of torch's zip reader, ...
        raise _damaged(path, describe(exc), zipped) from None
    if not isinstance(checkpoint, dict):
        raise ShapebenchError(
            f"checkpoint {path} is not a Lightning checkpoint (it holds a "
            f"{type(checkpoint).__name__}, not a dict with a state_dict)"
        )
    return checkpoint


def checkpoint_is_readable(path: Path) -> str | None:
    """Why the checkpoint at ``path`` cannot be used (one line naming it), or None if it loads.

    For a finished training whose ``last.ckpt`` was truncated or corrupted afterwards: the
    caller trains again instead of failing at evaluation.
    """
    try:
        load_safely(path)
    except ShapebenchError as exc:
        return exc.message
    return None


def key_of(path: Path, checkpoint: dict[str, Any] | None = None) -> str | None:
    """The checkpoint key ``path`` was trained under: stamped in the checkpoint itself, else
    recorded in ``done.json`` beside it (checkpoints trained before keys were stamped); None
    when neither says."""
    path = Path(path)
    if checkpoint is None:
        checkpoint = load_safely(path)
    stamp = checkpoint.get(STAMP)
    if isinstance(stamp, dict) and isinstance(stamp.get("key"), str):
        return stamp["key"]  # travels with the weights: the most reliable source
    done = path.parent / DONE_FILE
    try:
        record = json.loads(done.read_text())
    except (OSError, ValueError):
        return None
    key = record.get("key") if isinstance(record, dict) else None
    return key if isinstance(key, str) else None


def verify_checkpoint(
    path: Path, expected_key: str, checkpoint: dict[str, Any] | None = None
) -> None:
    """Raise :class:`ShapebenchError` naming both keys unless ``path`` was trained under
    ``expected_key`` (it also raises when the file is damaged, see :func:`load_safely`).

    ``checkpoint``: the dict already read from ``path``, to avoid reading it twice.
    """
    found = key_of(path, checkpoint)
    if found == expected_key:
        return
    what = f"checkpoint key {found}" if found else "no checkpoint key (not trained by shapebench?)"
    raise ShapebenchError(
        f"checkpoint {path} was trained under {what}, but this configuration has checkpoint "
        f"key {expected_key}; refusing to use it for this configuration",
        _retrain_hint(Path(path)),
    )


def checkpoint_problem(path: Path, expected_key: str) -> str | None:
    """Like :func:`verify_checkpoint`, but the reason as one line (None when the checkpoint
    loads and has ``expected_key``), for callers that retrain instead of failing."""
    try:
        verify_checkpoint(path, expected_key)
    except ShapebenchError as exc:
        return exc.message
    return None


def build_module(module_cls: type, checkpoint: dict[str, Any], path: Path):
    """A ``module_cls`` (LightningModule) built from the hyper-parameters saved in
    ``checkpoint`` and holding its weights, as Lightning's ``load_from_checkpoint`` would, but
    from a dict :func:`load_safely` already checked. A checkpoint of another model or of other
    sizes raises :class:`ShapebenchError` naming the file."""
    name = module_cls.__name__
    hparams = checkpoint.get("hyper_parameters")
    state = checkpoint.get("state_dict")
    if not isinstance(hparams, dict) or not isinstance(state, dict):
        raise ShapebenchError(
            f"checkpoint {path} is not a Lightning checkpoint of {name} "
            "(it lacks hyper_parameters or state_dict)",
            "pass a checkpoint written by 'shapebench train' for this method",
        )
    params = inspect.signature(module_cls.__init__).parameters
    takes_any = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
    kwargs = {k: v for k, v in hparams.items() if takes_any or k in params}
    try:
        module = module_cls(**kwargs)
        module.on_load_checkpoint(checkpoint)
        module.load_state_dict(state, strict=True)
    except (TypeError, ValueError, KeyError, RuntimeError) as exc:
        raise ShapebenchError(
            f"checkpoint {path} does not fit {name} ({describe(exc)})",
            "pass a checkpoint written by 'shapebench train' for this method",
        ) from None
    return module


def load_module(module_cls: type, path: Path, device: Any = "cpu"):
    """The ``module_cls`` stored at ``path``, on ``device``: :func:`load_safely` then
    :func:`build_module`."""
    checkpoint = load_safely(path, map_location="cpu")
    return build_module(module_cls, checkpoint, Path(path)).to(device)


# -- resuming a training ------------------------------------------------------------------------


def epochs_of(state: dict[str, Any]) -> int:
    """How many whole epochs the loaded checkpoint ``state`` holds (a mid-epoch one: those
    before its epoch)."""
    try:
        return int(state["loops"]["fit_loop"]["epoch_progress"]["current"]["processed"])
    except (KeyError, TypeError):
        return int(state.get("epoch", -1)) + 1


def checkpoint_epochs(path: Path) -> int | None:
    """How many whole epochs the checkpoint at ``path`` holds (a mid-epoch one: those before
    its epoch), or None if it cannot be read."""
    import torch

    try:
        return epochs_of(torch.load(path, map_location="cpu", weights_only=True))
    except Exception:
        return None


def describe_progress(state: dict[str, Any]) -> str:
    """How far a loaded checkpoint got, for messages."""
    return f"{epochs_of(state)} epochs done, optimiser step {int(state['global_step'])}"


def resume_state(last: Path, key: str) -> dict[str, Any] | None:
    """The checkpoint to resume from, read once, or None when there is none. A damaged one is
    reported and deleted (training restarts from epoch 0); one stamped with another key is
    refused, naming both."""
    import warnings

    if not last.exists():
        return None
    try:
        state = load_safely(last)
    except ShapebenchError as exc:
        warnings.warn(f"{exc.message}; training from epoch 0", CorruptFileWarning, stacklevel=2)
        last.unlink(missing_ok=True)
        return None
    if key_of(last, state) not in (None, key):
        verify_checkpoint(last, key, state)  # raises, naming both keys
    return state


def kept_message(last: Path) -> str:
    """What an interrupted training leaves to resume from, for its message."""
    import torch

    if not last.exists():
        return "nothing was saved yet"
    try:
        state = torch.load(last, map_location="cpu", weights_only=True)
    except Exception:
        return f"{last} is unreadable"
    return f"its checkpoint ({describe_progress(state)}) is kept at {last}"
