"""Completions made outside shapebench, scored on the same tables (issue 60): export, a loop in
another interpreter with numpy alone, ``shapebench import`` (the ``files`` method)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import TINY

import shapebench
from shapebench.api.errors import ConfigError

#: The novel split of the tiny benchmark: 4 objects, two sizes (the round trip: one).
CELLS = ("-d", "synthetic", *TINY, "--split", "novel", "--contexts", "50,100")
ONE_SIZE = (*CELLS[:-1], "100")

#: What a model in another environment runs: numpy alone, the manifest's paths. It completes
#: each context as ``gauss -O sigma=0`` does (every point repeated, in an order drawn from the
#: context's seed), so the built-in row gives the same scores object by object.
OUTSIDE = textwrap.dedent(
    """
    import json, sys
    from pathlib import Path
    import numpy as np
    root = Path(sys.argv[1])
    for e in json.loads((root / "manifest.json").read_text())["entries"]:
        pts, n = np.load(root / e["context"]), e["n_points"]
        rng = np.random.default_rng(e["context_seed"])
        c = np.repeat(pts, -(-n // len(pts)), axis=0)
        out = (c + rng.normal(scale=0.0, size=c.shape))[rng.permutation(len(c))[:n]]
        dest = root / (e["completion"] + ".npy")
        dest.parent.mkdir(parents=True, exist_ok=True)
        np.save(dest, out.astype(np.float32))
    assert not [m for m in sys.modules if m.startswith("shapebench")]
    """
)


def _export(sb, out: Path, cells: tuple[str, ...] = CELLS) -> None:
    res = sb("export", *cells, "--out", str(out), "-q")
    assert res.returncode == 0, res.stderr
    n = 4 * len(cells[-1].split(","))
    assert f"exported {n} contexts (4 objects of synthetic/novel" in res.stdout


def _complete_outside(folder: Path) -> None:
    # -I: isolated from PYTHONPATH and the user's site; only numpy is imported.
    subprocess.run([sys.executable, "-I", "-c", OUTSIDE, str(folder)], check=True, timeout=60)


def _results(sb) -> pd.DataFrame:
    return shapebench.load_results(
        "synthetic", "novel", tracking_uri=sb.tracking_uri, workspace=sb.workspace
    )


@pytest.mark.slow  # runs the CLI in subprocesses
def test_completions_from_outside_score_as_the_built_in_row_and_share_its_table(shapebench):
    sb = shapebench
    folder = sb.workspace / "exported"
    _export(sb, folder, ONE_SIZE)
    _complete_outside(folder)
    res = sb("import", str(folder), "--label", "outside", "-q")
    assert res.returncode == 0, res.stderr
    assert "outside on synthetic/novel" in res.stdout
    res = sb("run", "-m", "gauss", "-O", "sigma=0", *ONE_SIZE, "-q")
    assert res.returncode == 0, res.stderr

    table = _results(sb)
    keys = ["object", "context", "seed"]
    ours = table[table["label"] == "outside"].set_index(keys).sort_index()
    theirs = table[table["label"] == "gauss[sigma=0]"].set_index(keys).sort_index()
    assert len(ours) == len(theirs) == 4 and not ours["failed"].any()
    metrics = [c for c in ours.columns if c.startswith(("chamfer", "fscore"))]
    assert "chamfer-l2" in metrics
    for metric in metrics:
        np.testing.assert_allclose(ours[metric], theirs[metric], rtol=1e-6, atol=0)

    res = sb("leaderboard", "-d", "synthetic", "--split", "novel")
    assert res.returncode == 0, res.stderr
    board = (sb.workspace / "leaderboards" / "synthetic-novel.md").read_text()
    assert "Completions from files (`outside`)" in board
    csv = pd.read_csv(sb.workspace / "leaderboards" / "synthetic-novel.csv")
    assert {"outside", "gauss[sigma=0]"} <= set(csv["label"])
    assert "p_vs_best" in csv.columns  # the paired test against the best row


@pytest.mark.slow  # runs a sweep of two local workers
def test_the_exported_contexts_are_those_a_two_worker_sweep_hands_its_methods(shapebench):
    """Every files cell checks each context it is handed against the exported one's SHA-256 and
    fails that object otherwise: a sweep in two worker processes that scores every object, with
    the built-in row's scores, was handed the exported contexts."""
    sb = shapebench
    folder = sb.workspace / "exported"
    _export(sb, folder)
    _complete_outside(folder)
    options = dict(pair.split("=") for pair in TINY[1::2])
    sweep = sb.workspace / "byo.yaml"
    sweep.write_text(
        textwrap.dedent(
            f"""
            name: byo
            methods:
              - {{name: files, label: outside, options: {{root: "{folder}"}}}}
              - {{name: gauss, options: {{sigma: 0.0}}}}
            datasets:
              - name: synthetic
                options: {{{", ".join(f"{k}: {v}" for k, v in options.items())}}}
            splits: [novel]
            contexts: [50, 100]
            seeds: [0]
            """
        )
    )
    res = sb("sweep", str(sweep), "-q", "--launcher", "local", "-j", "2")
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    table = _results(sb)
    keys = ["object", "context", "seed"]
    ours = table[table["label"] == "outside"].set_index(keys).sort_index()
    theirs = table[table["label"] == "gauss[sigma=0]"].set_index(keys).sort_index()
    assert len(ours) == len(theirs) == 8 and not ours["failed"].any(), ours["reason"]
    np.testing.assert_allclose(ours["chamfer-l2"], theirs["chamfer-l2"], rtol=1e-6, atol=0)


@pytest.mark.slow  # runs the CLI in subprocesses
def test_bad_files_fail_their_objects_by_name_and_the_good_ones_score(shapebench):
    sb = shapebench
    folder = sb.workspace / "exported"
    _export(sb, folder)
    _complete_outside(folder)
    stems = sorted((folder / "completions" / "novel").rglob("n50-s0.npy"))
    missing, nan, garbage = stems[:3]
    missing.unlink()
    np.save(nan, np.full((10, 3), np.nan, dtype=np.float32))
    garbage.write_bytes(b"not an array")
    (folder / "completions" / "README.txt").write_text("not a completion")
    rel = [p.relative_to(folder).as_posix() for p in (missing, nan, garbage)]

    res = sb("import", str(folder), "--label", "partly", "-q")
    assert res.returncode == 0, res.stderr  # some objects of every cell scored
    assert res.stderr.count("README.txt") == 1  # named once, though the method is built twice
    assert "are not completions the manifest expects, ignored: completions/README.txt" in (
        res.stderr
    )
    assert f"no completion {rel[0][: -len('.npy')]}.* in {folder}" in res.stdout
    assert f"{rel[1]} has 10 NaN/inf points of 10" in res.stdout
    assert f"{rel[2]} is not a .npy file" in res.stdout

    table = _results(sb)
    table = table[table["label"] == "partly"]
    k50 = table[table["context"] == 50]
    assert k50["failed"].sum() == 3 and (~k50["failed"]).sum() == 1
    assert not table[table["context"] == 100]["failed"].any()
    reasons = " ".join(k50["reason"].dropna())
    assert all(r in reasons for r in (rel[0][: -len(".npy")], rel[1], rel[2]))

    res = sb("import", str(folder), "--label", "partly", "-q")
    assert res.stdout.count(" cached ") == 2  # the same files: the same cells
    # A changed file is a new cell, not a cache hit: every cell of the folder is computed again.
    _complete_outside(folder)
    res = sb("import", str(folder), "--label", "partly", "-q")
    assert res.returncode == 0, res.stderr
    assert res.stdout.count(" new ") == 2 and " cached " not in res.stdout


@pytest.mark.slow  # runs the CLI in subprocesses
def test_a_manifest_of_other_contexts_is_refused_naming_both(shapebench):
    sb = shapebench
    folder = sb.workspace / "exported"
    _export(sb, folder)
    res = sb("import", str(folder), "-D", "gt_points=1000", "-q")
    assert res.returncode == 2
    error = [ln for ln in res.stderr.splitlines() if ln.startswith("Error:")]
    assert len(error) == 1
    assert "was exported from dataset 'synthetic' (data fingerprint " in error[0]
    assert "this run's is 'synthetic' (data fingerprint " in error[0]
    # By hand with another protocol, every object fails saying why: no score of other points.
    res = sb("run", "-m", "files", "-O", f"root={folder}", *CELLS, "--protocol", "depth", "-q")
    assert res.returncode == 1
    assert "the run's protocol or context noise is not the export's" in res.stdout


def test_the_key_holds_the_folder_digest_and_a_missing_root_is_one_line(tmp_path):
    from shapebench_files.method import FilesMethod, FilesOptions

    from shapebench.api.protocol import Protocol
    from shapebench.exchange.manifest import Entry, Manifest

    stem = "novel/mug/mug__test-000/n50-s0"
    entry = Entry(
        "novel", "mug", "mug/test-000", 50, 0, 7, 2000, "0" * 64, "", f"completions/{stem}"
    )
    manifest = Manifest("synthetic", "1", {}, "f" * 16, "d" * 16, Protocol(), [], [], [], [entry])
    (tmp_path / "manifest.json").write_text(manifest.text())
    (tmp_path / "completions" / stem).parent.mkdir(parents=True)
    completion = tmp_path / "completions" / f"{stem}.npy"
    np.save(completion, np.zeros((5, 3), dtype=np.float32))

    def digest() -> str:
        return FilesMethod(FilesOptions(root=str(tmp_path))).options.digest

    with pytest.raises(ConfigError, match="none was given"):
        FilesMethod(FilesOptions())
    first = digest()
    assert len(first) == 64 and digest() == first
    (tmp_path / "completions" / "notes.txt").write_text("not a completion")
    with pytest.warns(UserWarning, match="ignored: completions/notes.txt"):
        assert digest() == first  # extra files are named, not scored, not in the key
    np.save(completion, np.ones((5, 3), dtype=np.float32))
    with pytest.warns(UserWarning, match="notes.txt"):  # named again: another folder's content
        assert digest() != first
