"""One cell, one configuration: keys hold everything that changes a result, a leaderboard row
is one variant, failures count, and orderings come with a paired test (issue: keys and rows)."""

from __future__ import annotations

import importlib
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import PLUGINS, TINY, pip_install_to
from scipy.stats import wilcoxon

from shapebench.api.protocol import Protocol
from shapebench.config import make_settings
from shapebench.registry.variant import auto_label, make_variant

RUN = ("-d", "synthetic", *TINY, "-q")


def _csv(sb, name: str) -> pd.DataFrame:
    return pd.read_csv(sb.workspace / "leaderboards" / name)


def _download(sb, run_id: str, name: str = "per_object.csv") -> pd.DataFrame:
    dst = sb.workspace / "dl" / run_id
    dst.mkdir(parents=True, exist_ok=True)
    path = sb.client().download_artifacts(run_id, name, str(dst))
    return pd.read_csv(path, keep_default_na=False, na_values=[""])


# ---------------------------------------------------------------------------------------- keys


@pytest.mark.slow  # runs the CLI in subprocesses
def test_max_epochs_is_part_of_the_checkpoint_key_and_the_row(with_example):
    sb = with_example
    short = sb(
        "run",
        "-m",
        "example-template",
        *RUN,
        "--contexts",
        "50",
        "--split",
        "novel",
        "--max-epochs",
        "3",
    )
    assert short.returncode == 0, short.stderr
    plain = sb("run", "-m", "example-template", *RUN, "--contexts", "50", "--split", "novel")
    assert plain.returncode == 0, plain.stderr
    assert "cached" not in plain.stdout  # the 3-epoch cells are not this configuration
    client = sb.client()
    train_exp = client.get_experiment_by_name("training/synthetic")
    trainings = client.search_runs([train_exp.experiment_id])
    assert len(trainings) == 2
    assert len({t.data.tags["checkpoint_key"] for t in trainings}) == 2
    cells = sb.cell_runs("synthetic-novel")
    assert len({c.data.tags["checkpoint_key"] for c in cells}) == 2
    epochs = sorted(c.data.params.get("training.epochs") for c in cells)
    assert epochs == ["3", "null"]  # the run's params show what was really used
    res = sb("leaderboard", "-d", "synthetic", "--reference", "example-template")
    assert res.returncode == 0, res.stderr
    labels = set(_csv(sb, "synthetic-novel.csv")["label"])
    # TINY trains on one shape per category where the profile says 6: the label says so too.
    assert labels == {
        "example-template[train_per_category=1]",
        "example-template[epochs=3,train_per_category=1]",
    }


def test_trainer_settings_that_change_weights_change_the_key(tmp_path):
    from shapebench.api.method import TrainerOptions
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method
    from shapebench.train.ticket import apply_trainer, checkpoint_key

    settings = make_settings(f"sqlite:///{tmp_path}/m.db", tmp_path, "quick", tmp_path)
    reg = get_registry()
    method = resolve_method(reg, "pcn", settings)
    data = resolve_dataset(reg, "synthetic", settings, None)

    def key(**kw) -> str:
        trainer = TrainerOptions(accelerator="cpu", **kw)
        return checkpoint_key(apply_trainer(method, trainer), data, trainer)

    base = key()
    assert key(max_epochs=3) != base
    assert key(precision="bf16-mixed") != base
    assert key(devices=2, strategy="ddp") != base  # twice the effective batch
    assert key(num_nodes=2) != base
    assert key(seed=1) != base
    assert key(strategy="ddp") == base  # one process either way: same weights
    assert apply_trainer(method, TrainerOptions(max_epochs=3)).options.epochs == 3
    # The profile's step budget: --max-steps changes it, --max-epochs replaces it by epochs.
    assert method.options.steps == 900
    assert key(max_steps=901) != base and key(max_steps=900) == base
    assert apply_trainer(method, TrainerOptions(max_steps=50)).options.steps == 50
    assert apply_trainer(method, TrainerOptions(max_epochs=3)).options.steps == 0
    assert key(max_epochs=3, max_steps=50) != key(max_steps=50)
    # So does an epochs option given over the profile (-O epochs=3, a sweep's options).
    assert resolve_method(reg, "pcn", settings, {"epochs": 3}).options.steps == 0
    assert resolve_method(reg, "pcn", settings, {"epochs": 3, "steps": 50}).options.steps == 50
    assert resolve_method(reg, "pcn", settings, {"lr": 0.01}).options.steps == 900


def test_the_training_scale_is_in_the_key_and_the_label_of_the_row(tmp_path):
    """A data-scaling sweep trains one method on more shapes: each scale is a checkpoint of its
    own and a row of its own, labelled so the rows read apart; the evaluation data is the same."""
    from shapebench.api.method import TrainerOptions
    from shapebench.evaluation.orchestrate import EvalRequest, _variant
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method
    from shapebench.train.ticket import checkpoint_key, training_ticket

    settings = make_settings(f"sqlite:///{tmp_path}/m.db", tmp_path, "quick", tmp_path)
    reg = get_registry()
    method = resolve_method(reg, "msc", settings)
    trainer = TrainerOptions(accelerator="cpu")
    rows = {}
    for scale in (None, 6, 20):  # 6 is the quick profile's own value
        opts = {} if scale is None else {"train_per_category": scale}
        data = resolve_dataset(reg, "synthetic", settings, None, opts)
        req = EvalRequest("msc", "synthetic", dataset_opts=opts)
        ticket = training_ticket(method, data, trainer, settings)
        variant = _variant(method, data, req, settings, ticket)
        rows[scale] = (checkpoint_key(method, data, trainer), variant, data.fingerprint())
    assert rows[None][0] == rows[6][0] != rows[20][0]
    assert rows[None][1] == rows[6][1] and rows[None][1].label == "msc"
    assert rows[20][1].key != rows[None][1].key
    assert rows[20][1].label == "msc[train_per_category=20]"
    assert rows[None][2] == rows[20][2]  # the same test objects: the rows can be compared


def test_more_test_objects_keep_every_checkpoint_key(tmp_path):
    """-D test_per_category=10 evaluates more objects with the same trained weights: the training
    objects do not depend on it, so neither does the checkpoint key; the evaluated set and its
    fingerprint (the cell keys) do. ShapeNet's cap on test models is the same kind of option."""
    from shapebench.api.method import TrainerOptions
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset, resolve_method
    from shapebench.train.ticket import checkpoint_key

    settings = make_settings(f"sqlite:///{tmp_path}/m.db", tmp_path, "quick", tmp_path)
    reg = get_registry()
    method = resolve_method(reg, "msc", settings)
    trainer = TrainerOptions(accelerator="cpu")
    small = resolve_dataset(reg, "synthetic", settings, None, {"test_per_category": 2})
    large = resolve_dataset(reg, "synthetic", settings, None, {"test_per_category": 10})
    assert checkpoint_key(method, small, trainer) == checkpoint_key(method, large, trainer)
    assert small.objects("train") == large.objects("train")
    assert small.fingerprint() != large.fingerprint()
    assert len(large.objects("trained")) == 5 * len(small.objects("trained"))
    # An option the training objects do depend on still changes the key.
    more = resolve_dataset(reg, "synthetic", settings, None, {"train_per_category": 20})
    assert checkpoint_key(method, more, trainer) != checkpoint_key(method, small, trainer)

    from shapebench_shapenet.dataset import ShapeNetOptions

    from shapebench.api.dataset import _options

    options = ShapeNetOptions(max_test_per_category=3)
    assert "max_test_per_category" in _options(options, training=False)
    assert "max_test_per_category" not in _options(options, training=True)
    assert "max_train_per_category" in _options(options, training=True)


def test_code_digest_follows_the_source(tmp_path, monkeypatch):
    from shapebench.registry import code_digest as cd

    pkg = tmp_path / "digest_probe"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "method.py").write_text("class M:\n    value = 1\n")
    (pkg / "helpers.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    cls = importlib.import_module("digest_probe.method").M
    first = cd.code_digest(cls)
    assert first == cd.code_digest(cls)
    (pkg / "helpers.py").write_text("X = 2\n")  # any file of the package counts
    cd._digest_files.cache_clear()
    assert cd.code_digest(cls) != first
    sys.modules.pop("digest_probe.method", None)
    sys.modules.pop("digest_probe", None)


def test_code_digest_does_not_depend_on_where_the_code_lives(tmp_path, monkeypatch):
    """Two checkouts (or a cluster node and a laptop) with the same code share keys, also when a
    method's package and a shared module it names live under different roots."""
    from shapebench.registry import code_digest as cd

    def install(method_root: Path, shared_root: Path) -> str:
        for name in [m for m in sys.modules if m.startswith(("probe_m", "probe_shared"))]:
            sys.modules.pop(name)
        (method_root / "probe_m").mkdir(parents=True)
        (method_root / "probe_m" / "__init__.py").write_text("")
        (method_root / "probe_m" / "method.py").write_text(
            "class M:\n    code_modules = ('probe_shared.mod',)\n"
        )
        (shared_root / "probe_shared").mkdir(parents=True)
        (shared_root / "probe_shared" / "__init__.py").write_text("")
        (shared_root / "probe_shared" / "mod.py").write_text("Y = 1\n")
        monkeypatch.syspath_prepend(str(method_root))
        monkeypatch.syspath_prepend(str(shared_root))
        cls = importlib.import_module("probe_m.method").M
        assert str(shared_root) in importlib.import_module("probe_shared.mod").__file__
        return cd.code_digest(cls)

    # The method's root sorts first in one layout and last in the other.
    first = install(tmp_path / "a" / "m", tmp_path / "z" / "s")
    second = install(tmp_path / "zz" / "m", tmp_path / "aa" / "s")
    for name in [m for m in sys.modules if m.startswith(("probe_m", "probe_shared"))]:
        sys.modules.pop(name)
    assert first == second


#: Imports a digest knowingly leaves out (file that imports -> module it imports), each with why.
#: The implicit methods cover the mesh extraction through ``completion_modules`` (cell keys);
#: PCN hashes the implicit package for its networks and never meshes.
KNOWN_UNCOVERED = {("shapebench.implicit/completion.py", "shapebench.geometry.meshing")}


def _imported_modules(path: Path) -> set[str]:
    import ast

    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module)
    return names


def test_every_builtin_method_key_covers_the_code_its_plugin_imports():
    """A method's code digest names the files its results come from: a plugin file that imports
    another plugin's module, a shared non-core module (``shapebench.implicit``,
    ``shapebench.geometry``) or a core training module must have it in its digest, or an edit
    there would reuse stale checkpoints and cells. (PCN imported ``shapebench.implicit.networks``
    uncovered until its standard configuration.) The contract (``shapebench.api``) and the
    ``shapebench`` package's hook marker are exempt, and so are the imports of core files, which
    stand for themselves by design (:mod:`shapebench.registry.code_digest`)."""
    from shapebench.registry.code_digest import _module_sources, digest_sources
    from shapebench.registry.discovery import get_registry

    registry = get_registry()
    missing = []
    for name in registry.names("method"):
        registration = registry.get("method", name)
        if registration.plugin.distribution != "shapebench":
            continue  # a third party's holes are its own
        cls = registration.load()
        sources = digest_sources(cls)
        # The completion code (mesh extraction, sampling) is covered by the cell key alone.
        completion = {f.resolve() for m in cls.completion_modules for _, f in _module_sources(m)}
        covered = {path.resolve() for path in sources.values()} | completion
        for label, path in sorted(sources.items()):
            if "/" not in label:
                continue  # a core file (``module.py``): stands for itself
            for module in sorted(_imported_modules(path)):
                if module == "shapebench" or module.startswith("shapebench.api"):
                    continue
                if not module.startswith("shapebench"):
                    continue  # torch, numpy: versions are keyed apart
                files = {f.resolve() for _, f in _module_sources(module)}
                meshes = bool(cls.completion_modules)
                exempt = (label, module) in KNOWN_UNCOVERED and not meshes
                if not files <= covered and not exempt:
                    missing.append(f"{name}: {label} imports {module}, not in its digest")
    assert not missing, "\n".join(sorted(set(missing)))


@pytest.mark.slow  # runs the CLI in subprocesses
def test_an_edited_plugin_does_not_reuse_its_stale_cells(shapebench, tmp_path):
    site = pip_install_to(tmp_path / "site", PLUGINS / "shapebench-example")
    shapebench.sites = (site,)
    args = ("run", "-m", "example-sphere", *RUN, "--contexts", "50", "--split", "novel")
    assert shapebench(*args).returncode == 0
    again = shapebench(*args)
    assert "cached" in again.stdout
    source = site / "shapebench_example" / "methods.py"
    source.write_text(source.read_text() + "\n# edited by hand\n")
    edited = shapebench(*args)
    assert edited.returncode == 0, edited.stderr
    assert "cached" not in edited.stdout and "new" in edited.stdout
    codes = {c.data.tags["method.code"] for c in shapebench.cell_runs("synthetic-novel")}
    assert len(codes) == 2


# ------------------------------------------------------------------------------------ variants


def test_variant_key_and_label():
    p = Protocol()
    cfg = {"name": "gauss", "options": {"sigma": 0.01}, "code": "c"}
    a = make_variant("gauss", cfg, {}, p, "quick")
    b = make_variant("gauss", {**cfg, "options": {"sigma": 0.05}}, {"sigma": 0.05}, p, "quick")
    assert a.label == "gauss" and b.label == "gauss[sigma=0.05]" and a.key != b.key
    assert make_variant("gauss", cfg, {}, p, "paper").label == "gauss[profile=paper]"
    n = make_variant("gauss", cfg, {}, Protocol(context_normals=True), "quick")
    assert n.label == "gauss+normals" and n.key != a.key
    assert make_variant("gauss", cfg, {}, p, "quick", label="mine").label == "mine"
    assert auto_label("igr", {"width": 64, "lr": 1e-3}) == "igr[lr=0.001,width=64]"


def test_a_checkpoint_given_by_path_is_keyed_by_its_contents(tmp_path):
    """``run --checkpoint``: a copy of the file elsewhere (a fresh clone, another machine)
    gives the same cells and row; an edited file does not; the row names the file."""
    from shapebench.train.references import given_checkpoint

    a, b = tmp_path / "a" / "model.ckpt", tmp_path / "b" / "copy.ckpt"
    a.parent.mkdir()
    b.parent.mkdir()
    a.write_bytes(b"weights" * 100)
    b.write_bytes(a.read_bytes())
    given_a, given_b = given_checkpoint(a), given_checkpoint(b)
    assert given_a.digest == given_b.digest and len(given_a.digest) == 16
    assert (given_a.name, given_b.name) == ("model.ckpt", "copy.ckpt")
    b.write_bytes(b"other weights")
    assert given_checkpoint(b).digest != given_a.digest

    p, cfg = Protocol(), {"name": "msc", "options": {}, "code": "c"}
    row_a = make_variant(
        "msc", cfg, {}, p, "quick", checkpoint_file=given_a.digest, checkpoint_name=given_a.name
    )
    row_b = make_variant(
        "msc", cfg, {}, p, "quick", checkpoint_file=given_b.digest, checkpoint_name=given_b.name
    )
    assert row_a.key == row_b.key and row_a.label == "msc[checkpoint=model.ckpt]"


def test_a_shipped_reference_given_by_path_is_named_by_its_key():
    from shapebench.train.references import SHIPPED, find, given_checkpoint

    info = sorted(SHIPPED.glob("*/*/reference.json"))[0]
    ref = find(info.parent.parent.name, info.parent.name)
    given = given_checkpoint(ref.checkpoint)
    assert given.name == f"{info.parent.parent.name}/{info.parent.name}"
    assert given.digest == ref.info["sha256"][:16]


@pytest.mark.slow  # runs the CLI in subprocesses
def test_a_sigma_variant_gets_its_own_row(shapebench):
    sb = shapebench
    assert (
        sb("run", "-m", "gauss", *RUN, "--contexts", "50,100", "--split", "novel").returncode == 0
    )
    res = sb("run", "-m", "gauss", *RUN, "--contexts", "50", "--split", "novel", "-O", "sigma=0.05")
    assert res.returncode == 0, res.stderr
    assert "gauss[sigma=0.05] on synthetic/novel" in res.stdout
    assert sb("leaderboard", "-d", "synthetic", "--reference", "gauss").returncode == 0
    md = (sb.workspace / "leaderboards" / "synthetic-novel.md").read_text()
    csv = _csv(sb, "synthetic-novel.csv")
    raw = csv[csv.kind == "raw"]
    wide = raw[raw.label == "gauss[sigma=0.05]"]
    assert wide["context"].tolist() == [50]  # it lacks 100: "–" there, never another variant
    row = next(line for line in md.splitlines() if "`gauss[sigma=0.05]`) |" in line)
    assert row.split("|")[2].strip() != "–" and row.split("|")[3].strip() == "–"
    assert "* `gauss[sigma=0.05]`: gauss, sigma=0.05" in md
    # The plain row is computed from the sigma 0.01 runs only.
    plain = raw[(raw.label == "gauss") & (raw.context == 50)]["mean"].item()
    assert not np.isclose(plain, wide["mean"].item())


@pytest.mark.slow  # runs the CLI in subprocesses
def test_a_label_names_the_row(shapebench):
    res = shapebench(
        "run",
        "-m",
        "gauss",
        *RUN,
        "--contexts",
        "50",
        "--split",
        "novel",
        "--label",
        "gauss-baseline",
    )
    assert res.returncode == 0, res.stderr
    assert (
        shapebench("leaderboard", "-d", "synthetic", "--reference", "gauss-baseline").returncode
        == 0
    )
    assert set(_csv(shapebench, "synthetic-novel.csv")["label"]) == {"gauss-baseline"}


@pytest.mark.slow  # runs the CLI in subprocesses
def test_context_normals_are_a_protocol_option_not_a_paper_row(shapebench):
    sb = shapebench
    args = ("run", "-m", "gauss", *RUN, "--contexts", "50", "--split", "novel")
    assert sb(*args).returncode == 0
    assert sb(*args, "--context-normals").returncode == 0
    runs = sb.cell_runs("synthetic-novel")
    by_flag = {r.data.tags["protocol.context_normals"]: r for r in runs}
    assert set(by_flag) == {"True", "False"}
    with np.load(
        sb.client().download_artifacts(
            by_flag["False"].info.run_id, "contexts.npz", str(sb.workspace)
        )
    ) as z:
        assert "normals" not in z.files  # the default protocol gives points only
    assert sb("leaderboard", "-d", "synthetic", "--reference", "gauss").returncode == 0
    md = (sb.workspace / "leaderboards" / "synthetic-novel.md").read_text()
    assert "| Gauss densification + test-time normals (`gauss+normals`) |" in md
    assert "except rows marked +normals" in md


def test_the_context_store_gives_normals_only_when_asked(tmp_path):
    from shapebench.api.contexts import ContextStore
    from shapebench.api.types import ObjectData, ObjectRef

    pts = np.random.default_rng(0).normal(size=(200, 3)).astype(np.float32)
    data = ObjectData(ObjectRef("a", "c"), pts, pts, pts)
    store = ContextStore(tmp_path, "fp")
    assert store.context(data, 50, 0).normals is None
    with_normals = store.context(data, 50, 0, normals=True)
    np.testing.assert_array_equal(with_normals.points, store.context(data, 50, 0).points)
    assert with_normals.normals.shape == (50, 3)


# ---------------------------------------------------------------------------------- data sets


def test_split_options_keep_the_preprocessing_cache(tmp_path):
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset

    settings = make_settings(f"sqlite:///{tmp_path}/m.db", tmp_path, "quick", tmp_path)
    reg = get_registry()
    a = resolve_dataset(reg, "synthetic", settings, None, {"test_per_category": 1})
    b = resolve_dataset(reg, "synthetic", settings, None, {"test_per_category": 3})
    assert a.cache_root == b.cache_root and a.data_fingerprint() == b.data_fingerprint()
    assert a.fingerprint() != b.fingerprint()  # another evaluated set: other cell keys
    c = resolve_dataset(reg, "synthetic", settings, None, {"gt_points": 1000})
    assert c.cache_root != a.cache_root  # a processing option does change the arrays
    from shapebench_meshes.dataset import MeshFolderOptions
    from shapebench_shapenet.dataset import ShapeNetOptions

    selection = {
        f.name for f in ShapeNetOptions.__dataclass_fields__.values() if f.metadata.get("selection")
    }
    assert {"test_fraction", "max_test_per_category", "split_dir", "categories"} <= selection
    assert MeshFolderOptions.__dataclass_fields__["train_fraction"].metadata["selection"]


@pytest.mark.slow  # runs the CLI in subprocesses
def test_an_explicitly_requested_empty_split_is_an_error(shapebench):
    res = shapebench(
        "run",
        "-m",
        "gauss",
        "-d",
        "synthetic",
        *TINY,
        "-D",
        "test_per_category=0",
        "--split",
        "novel",
        "--contexts",
        "50",
    )
    assert res.returncode == 2
    assert "split novel of dataset 'synthetic' has no objects" in res.stderr
    assert "Traceback" not in res.stderr


@pytest.mark.slow  # runs the CLI in subprocesses
def test_run_prints_what_is_evaluated(shapebench):
    res = shapebench("run", "-m", "gauss", *RUN, "--contexts", "50", "--split", "novel")
    assert "synthetic/novel: 4 objects in 4 categories" in res.stdout
    assert "test_per_category" in res.stdout


@pytest.mark.slow  # runs the CLI in subprocesses
def test_the_leaderboard_picks_a_data_version(shapebench):
    sb = shapebench
    base = ("run", "-m", "gauss", *RUN, "--contexts", "50", "--split", "novel")
    assert sb(*base, "-D", "gt_points=1000").returncode == 0
    assert sb(*base).returncode == 0
    assert sb("leaderboard", "-d", "synthetic", "--reference", "gauss").returncode == 0
    md = (sb.workspace / "leaderboards" / "synthetic-novel.md").read_text()
    newest = _csv(sb, "synthetic-novel.csv")["fingerprint"].iloc[0]
    assert f"dataset fingerprint `{newest}`" in md and "2000 eval points" in md
    assert "runs on other data versions" in md and "--data-version" in md
    fps = {r.data.tags["dataset.fingerprint"] for r in sb.cell_runs("synthetic-novel")}
    older = (fps - {newest}).pop()
    res = sb("leaderboard", "-d", "synthetic", "--reference", "gauss", "--data-version", older[:8])
    assert res.returncode == 0, res.stderr
    md = (sb.workspace / "leaderboards" / "synthetic-novel.md").read_text()
    assert f"dataset fingerprint `{older}`" in md and "1000 eval points" in md
    bad = sb("leaderboard", "-d", "synthetic", "--data-version", "zzzz")
    assert bad.returncode == 2 and "matches 0 of the data versions" in bad.stderr


# ------------------------------------------------------------------------------------ failures


@pytest.mark.slow  # runs the CLI in subprocesses
def test_a_cell_where_every_object_fails_exits_non_zero_with_reasons(shapebench):
    res = shapebench(
        "run", "-m", "gauss", *RUN, "--contexts", "50", "--split", "novel", "-O", "sigma=.nan"
    )
    assert res.returncode == 1
    assert "EVERY object failed" in res.stdout
    assert "4 x completion has" in res.stdout and "NaN/inf points" in res.stdout
    assert "per_object.csv" in res.stdout
    assert "every object failed in 1 cell(s)" in res.stderr


def _holm(p: list[float]) -> list[float]:
    order = sorted(range(len(p)), key=lambda i: p[i])
    out, running = [0.0] * len(p), 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(p) - rank) * p[i]))
        out[i] = running
    return out


@pytest.mark.slow  # runs the CLI in subprocesses
def test_failure_rule_and_tied_marks_recomputed_from_the_per_object_tables(with_example):
    sb = with_example
    for extra in ((), ("-O", "sigma=0.05"), ("-O", "sigma=0.011")):
        assert (
            sb(
                "run", "-m", "gauss", *RUN, "--contexts", "50", "--split", "trained", *extra
            ).returncode
            == 0
        )
    assert (
        sb("run", "-m", "example-flaky", *RUN, "--contexts", "50", "--split", "trained").returncode
        == 0
    )
    assert (
        sb(
            "leaderboard", "-d", "synthetic", "--split", "trained", "--reference", "gauss"
        ).returncode
        == 0
    )
    csv = _csv(sb, "synthetic-trained.csv")
    raw = csv[(csv.kind == "raw") & (csv.context == 50)].set_index("label")
    tables = {}
    for run in sb.cell_runs("synthetic-trained"):
        table = _download(sb, run.info.run_id).set_index("object")
        ok = table["status"] == "ok"
        worst = table.loc[ok, "chamfer-l2"].max()
        tables[run.data.tags["variant.label"]] = table["chamfer-l2"].where(ok, worst)
    flaky = tables["example-flaky"]
    assert raw.loc["example-flaky", "failures"] > 0
    assert np.isclose(raw.loc["example-flaky", "mean"], 1000 * flaky.mean())
    assert raw.loc["example-flaky", "n_ok"] < raw.loc["example-flaky", "n"] == 11
    # The tied group, from scratch: best mean, Wilcoxon against it, Holm over the others.
    means = {label: s.mean() for label, s in tables.items()}
    best = min(means, key=means.get)
    others = sorted(set(tables) - {best}, key=lambda lb: raw.loc[lb, "variant"])
    p = [wilcoxon(tables[best], tables[o].loc[tables[best].index]).pvalue for o in others]
    for label, adj in zip(others, _holm(p), strict=True):
        assert np.isclose(raw.loc[label, "p_holm"], adj)
        assert bool(raw.loc[label, "tied"]) == (adj >= 0.05)
    assert bool(raw.loc[best, "best"])
    md = (sb.workspace / "leaderboards" / "synthetic-trained.md").read_text()
    assert "Wilcoxon signed-rank" in md and "Holm" in md
    assert f"/{11} ok)" in md  # flaky's cell says how many objects succeeded


def test_the_failure_rule_on_a_known_table():
    from shapebench.boards import stats as board_stats

    rows = [
        ("a", "x", "ok", 1.0),
        ("a", "y", "ok", 3.0),
        ("a", "z", "failed", np.nan),
        ("b", "x", "ok", 2.0),
        ("b", "y", "failed", np.nan),
        ("b", "z", "failed", np.nan),
        ("c", "x", "failed", np.nan),
        ("c", "y", "failed", np.nan),
        ("c", "z", "failed", np.nan),
    ]
    df = pd.DataFrame(rows, columns=["variant", "object", "status", "value"])
    df = df.assign(label=df.variant, context=50, seed=0)
    raw = board_stats.raw_table(board_stats.with_failure_rule(df)).set_index("variant")
    assert raw.loc["a", "mean"] == pytest.approx((1 + 3 + 3) / 3)
    assert raw.loc["a", "mean_ok"] == pytest.approx(2.0)
    assert raw.loc["b", "mean"] == pytest.approx(2.0) and raw.loc["b", "n_ok"] == 1
    assert np.isnan(raw.loc["c", "mean"]) and raw.loc["c", "n_ok"] == 0
    assert board_stats.holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])


def test_the_paired_shift_points_the_way_the_typical_pair_does():
    from shapebench.boards import stats as board_stats

    # Differences 1, 1, 1, -30: `a` is higher on three pairs of four but far lower on one, so its
    # mean is lower; the shift (the median of the ten Walsh averages: six 1s, three -14.5s and
    # -30) is 1: the typical pair has `a` higher, as the count of pairs says.
    a, b = np.array([2.0, 3.0, 4.0, 0.0]), np.array([1.0, 2.0, 3.0, 30.0])
    assert a.mean() < b.mean()
    assert board_stats.paired_shift(a, b) == pytest.approx(1.0)
    assert board_stats.paired_shift(b, a) == pytest.approx(-1.0)
    assert board_stats.paired_shift(a, a) == 0.0
    assert np.isnan(board_stats.paired_shift(a[:0], b[:0]))


def test_the_paired_shift_of_a_large_board_selects_the_same_walsh_averages():
    """Above two million Walsh averages the shift is selected without forming them; the
    selection gives every rank the full sort gives, ties and negative differences included."""
    from shapebench.boards import stats as board_stats

    rng = np.random.default_rng(0)
    for diff in (rng.normal(size=40), np.round(rng.normal(size=41), 1), np.zeros(5)):
        ordered = np.sort(diff)
        i, j = np.triu_indices(len(diff))
        walsh = np.sort((diff[i] + diff[j]) / 2)
        picked = [board_stats._walsh_order_statistic(ordered, k) for k in range(1, len(walsh) + 1)]
        assert np.allclose(picked, walsh, rtol=0, atol=1e-12)
    # 2,500 pairs (3.1 million averages) take the selecting path; half of them by chance higher.
    a, b = rng.normal(size=2500) + 0.25, rng.normal(size=2500)
    i, j = np.triu_indices(len(a))
    assert len(i) > board_stats._WALSH_IN_MEMORY
    expected = np.median((a - b)[i] + (a - b)[j]) / 2
    assert board_stats.paired_shift(a, b) == pytest.approx(expected, abs=1e-12)


def test_the_category_mean_weighs_every_category_the_same():
    from shapebench.boards import stats as board_stats

    # Three chairs (1, 2, 3) and one lamp (10): the instance mean is 16/4 = 4, the category mean
    # (PCN's "overall") (2 + 10)/2 = 6. A failed chair scores the worst value of its cell, 10.
    rows = [
        ("chair/0", "chair", "ok", 1.0),
        ("chair/1", "chair", "ok", 2.0),
        ("chair/2", "chair", "ok", 3.0),
        ("lamp/0", "lamp", "ok", 10.0),
    ]
    df = pd.DataFrame(rows, columns=["object", "category", "status", "value"])
    df = df.assign(variant="a", label="a", context=50, seed=0)
    raw = board_stats.raw_table(board_stats.with_failure_rule(df)).iloc[0]
    assert raw["mean"] == pytest.approx(4.0) and raw["category_mean"] == pytest.approx(6.0)
    assert raw["categories"] == 2
    df.loc[0, ["status", "value"]] = ["failed", np.nan]
    raw = board_stats.raw_table(board_stats.with_failure_rule(df)).iloc[0]
    assert raw["category_mean"] == pytest.approx(((10 + 2 + 3) / 3 + 10) / 2)


# ----------------------------------------------------------------------------- paper's column


def test_the_paper_column_stands_only_beside_the_unit_diameter_card():
    from shapebench.boards.board import Board, Row
    from shapebench.boards.markdown import render_markdown
    from shapebench.boards.paper import paper_table
    from shapebench.boards.tidy import tidy_csv

    raw = pd.DataFrame(
        [
            {
                "variant": "v",
                "label": "gauss",
                "context": 50,
                "mean": 1.0,
                "std": 0.5,
                "mean_ok": 1.0,
                "std_ok": 0.5,
                "n": 3,
                "n_ok": 3,
                "failures": 0,
            }
        ]
    )
    sig = pd.DataFrame(
        [
            {
                "variant": "v",
                "context": 50,
                "best": True,
                "tied": False,
                "p_vs_best": np.nan,
                "p_holm": np.nan,
                "n_pairs": 3,
            }
        ]
    )
    rows = [Row("v", "gauss", "gauss", "Gauss densification", {})]
    card = (
        "metric=chamfer-l2;power=2;reduction=mean;direction=symmetric;halved=False;"
        "scale=1000.0;frame={};eval_points=30000"
    )

    def board(frame: str) -> Board:
        return Board(
            "shapenet",
            "novel",
            "chamfer-l2",
            card.format(frame),
            "msc-noopt",
            [50],
            rows,
            raw,
            None,
            sig,
            "",
            paper_table("shapenet", "novel"),
            "1",
            "f",
            frame=frame,
        )

    radius = render_markdown(board("unit-radius"), "cmd", "sqlite:///x")
    diameter = render_markdown(board("unit-diameter"), "cmd", "sqlite:///x")
    assert "(paper)" not in radius and "--frame unit-diameter" in radius
    assert "| Gauss densification (paper) | 2.97 ± 1.65 | 4.33 ± 4.98 |" in diameter  # Table 2
    assert "| Gauss densification (`gauss`) | **1.00 ± 0.50** |" in diameter
    assert "paper" not in set(tidy_csv(board("unit-radius"))["source"])
    assert "paper" in set(tidy_csv(board("unit-diameter"))["source"])


@pytest.mark.slow  # runs the CLI in subprocesses
def test_the_unit_diameter_frame_divides_squared_chamfer_by_four(shapebench):
    sb = shapebench
    args = ("run", "-m", "gauss", *RUN, "--contexts", "50", "--split", "novel")
    assert sb(*args).returncode == 0
    assert sb(*args, "--frame", "unit-diameter").returncode == 0
    runs = {r.data.tags["protocol.frame"]: r for r in sb.cell_runs("synthetic-novel")}
    radius = _download(sb, runs["unit-radius"].info.run_id).set_index("object")
    diameter = _download(sb, runs["unit-diameter"].info.run_id).set_index("object")
    np.testing.assert_allclose(diameter["chamfer-l2"], radius["chamfer-l2"] / 4, rtol=1e-5)
    np.testing.assert_allclose(diameter["chamfer-l1"], radius["chamfer-l1"] / 2, rtol=1e-5)
    assert "frame=unit-diameter" in runs["unit-diameter"].data.tags["card.chamfer-l2"]


@pytest.mark.slow  # runs the CLI in subprocesses
def test_sweep_files_take_the_protocol_and_labels(shapebench, tmp_path):
    sweep = tmp_path / "s.yaml"
    sweep.write_text(
        textwrap.dedent("""
        methods: [{name: gauss, options: {sigma: 0.02}, label: gauss-wide}]
        datasets: [{name: synthetic, options: {test_per_category: 1, train_per_category: 1,
                    surface_candidates: 3000, gt_points: 2000}}]
        splits: [novel]
        contexts: [50]
        frame: unit-diameter
    """)
    )
    res = shapebench("sweep", str(sweep), "-q")
    assert res.returncode == 0, res.stderr
    (run,) = shapebench.cell_runs("synthetic-novel")
    assert run.data.tags["variant.label"] == "gauss-wide"
    assert run.data.tags["protocol.frame"] == "unit-diameter"


@pytest.mark.slow  # runs the CLI in subprocesses
def test_training_child_imports_the_same_shapebench_as_its_parent(with_example):
    """A folder named shapebench in the working directory (a second checkout) must not be what
    the training process imports: the console script's process does not import it, and the
    training child it starts with `python -m` must not either."""
    import subprocess

    here = with_example.workspace / "elsewhere"
    shadow = here / "shapebench"
    shadow.mkdir(parents=True)
    (shadow / "__init__.py").write_text("raise ImportError('the shadow copy was imported')\n")
    (shadow / "__main__.py").write_text("raise SystemExit('the shadow copy ran')\n")
    script = Path(sys.executable).parent / "shapebench"
    res = subprocess.run(
        [
            str(script),
            "run",
            "-m",
            "example-template",
            *RUN,
            "--contexts",
            "50",
            "--split",
            "novel",
        ],
        cwd=here,
        env=with_example.env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    assert "shadow" not in res.stderr


@pytest.mark.slow  # runs the CLI in subprocesses
def test_the_validation_split_is_apart_from_the_test_objects_and_run_only_when_named(shapebench):
    from shapebench.api.types import TRAIN, TRAINED, VALIDATION
    from shapebench.config import make_settings
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_dataset

    settings = make_settings(None, str(shapebench.cache), None, shapebench.workspace)
    options = {"test_per_category": 2, "train_per_category": 3}
    ds = resolve_dataset(get_registry(), "synthetic", settings, None, options)
    ids = {s: {r.id for r in ds.objects(s)} for s in (TRAIN, TRAINED, VALIDATION)}
    assert len(ids[VALIDATION]) == 2 * 11  # test_per_category of each trained category
    assert all("/val-" in i for i in ids[VALIDATION])
    assert not ids[VALIDATION] & (ids[TRAIN] | ids[TRAINED])
    # Other objects, not renamed copies: their meshes differ from the test objects'.
    val, test = ds.mesh(ds.objects(VALIDATION)[0]), ds.mesh(ds.objects(TRAINED)[0])
    assert val.vertices.shape != test.vertices.shape or not np.allclose(val.vertices, test.vertices)

    res = shapebench("run", "-m", "gauss", "-d", "synthetic", *TINY, "--contexts", "50", "-q")
    assert res.returncode == 0, res.stderr
    assert "synthetic/validation" not in res.stdout  # not a default split, never on a table
    assert shapebench.cell_runs("synthetic-validation") == []
    res = shapebench(
        "run", "-m", "gauss", "-d", "synthetic", *TINY, "--contexts", "50", "--split", "validation"
    )
    assert res.returncode == 0, res.stderr
    assert "synthetic/validation: 11 objects in 11 categories (1 validation object" in res.stdout
    runs = shapebench.cell_runs("synthetic-validation")
    assert len(runs) == 1
    res = shapebench("run", "-m", "gauss", "-d", "synthetic", *TINY, "--split", "valid")
    assert res.returncode == 2 and "use one of: trained, novel, validation" in res.stderr


def test_the_completion_code_is_in_the_cell_key_and_not_the_checkpoint_key():
    """Mesh extraction and sampling shape an implicit row's cells but not its training: their
    digest is in the cell's method config, not in the training's, and a method that names no
    completion modules has the config it had before the digest existed."""
    from shapebench.config import make_settings
    from shapebench.registry.code_digest import completion_digest, digest_sources
    from shapebench.registry.discovery import get_registry
    from shapebench.registry.resolve import resolve_method

    registry, settings = get_registry(), make_settings()
    igr = resolve_method(registry, "igr", settings)
    assert igr.config()["completion_code"] == completion_digest(igr.cls) != ""
    assert "completion_code" not in igr.training_config()
    assert not any("meshing" in name for name in digest_sources(igr.cls))
    gauss = resolve_method(registry, "gauss", settings)
    assert "completion_code" not in gauss.config() and completion_digest(gauss.cls) == ""
