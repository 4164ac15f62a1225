"""The cluster launcher's pieces that need no cluster: its config, the tracking rule, the ranks
of a training job, and the plan of what a sweep still has to do."""

from __future__ import annotations

import pytest
from conftest import TINY, TINY_CONTEXTS

from shapebench.api.errors import ConfigError, ShapebenchError
from shapebench.config import make_settings
from shapebench.sweeps.cluster import (
    LauncherConfig,
    _ranks,
    check_tracking,
    launcher_config,
    read_manifest,
)
from shapebench.sweeps.spec import load_sweep


def test_launcher_block_then_command_line_then_per_method_overrides():
    block = {
        "name": "slurm",
        "partition": "gpu",
        "time": 240,
        "gpus_per_node": 1,
        "methods": {"gauss": {"gpus_per_node": 0, "time": 10}},
    }
    cfg = launcher_config(block, {"time": "30", "extra": {"mail-type": "END"}}, None)
    assert (cfg.name, cfg.partition, cfg.time, cfg.gpus_per_node) == ("slurm", "gpu", 30, 1)
    gauss = cfg.for_method("gauss")
    assert (gauss.gpus_per_node, gauss.time, gauss.partition) == (0, 10, "gpu")
    assert cfg.for_method("igr") == cfg
    assert launcher_config(block, {}, "submitit-local").name == "submitit-local"


@pytest.mark.parametrize(
    "block, message",
    [
        ({"partiton": "gpu"}, "unknown launcher keys ['partiton']"),
        ({"time": "two hours"}, "time must be a number"),
        ({"tracking": "nfs"}, "'server' or 'per-job'"),
        ({"cells_per_job": 0}, "at least 1"),
        ({"methods": {"igr": {"gpu": 1}}}, "launcher.methods.igr"),
    ],
)
def test_bad_launcher_keys_are_named(block, message):
    with pytest.raises(ConfigError) as err:
        launcher_config(block, {}, None).for_method("igr")
    assert message in str(err.value.message)


def test_a_slurm_sweep_refuses_one_sqlite_store_for_every_job(tmp_path):
    settings = make_settings(workspace=tmp_path)
    with pytest.raises(ShapebenchError) as err:
        check_tracking(LauncherConfig(name="slurm"), settings)
    assert "SQLite" in err.value.message and "per-job" in err.value.hint
    check_tracking(LauncherConfig(name="slurm", tracking="per-job"), settings)
    check_tracking(LauncherConfig(name="submitit-local"), settings)  # one machine: fine
    remote = make_settings(tracking_uri="http://127.0.0.1:5000", workspace=tmp_path)
    check_tracking(LauncherConfig(name="slurm"), remote)


def test_a_training_job_has_one_task_per_lightning_rank():
    assert _ranks({}) == (1, 1)
    assert _ranks({"devices": "4", "num_nodes": 2}) == (4, 2)
    assert _ranks({"devices": "0,1"}) == (2, 1)


def test_a_pickled_job_names_its_callable_in_the_jobs_module(tmp_path):
    """submitit pickles a job's callable by reference: a node imports it from
    shapebench.sweeps.jobs, and a job pickled when the classes lived in shapebench.sweeps.cluster
    (requeued after an upgrade) still finds them there."""
    import io
    import pickle

    cloudpickle = pytest.importorskip("cloudpickle")  # what submitit pickles with
    from shapebench.sweeps import jobs

    ctx = jobs.JobContext("s.yaml", None, "", str(tmp_path), str(tmp_path), {})
    for job in (
        jobs.CellsJob(ctx, []),
        jobs.TrainingJob(ctx, None),
        jobs.PrepareJob(None, None, 0, 1, 1),
    ):
        data = cloudpickle.dumps(job)
        assert b"shapebench.sweeps.jobs" in data and b"shapebench.sweeps.cluster" not in data
        assert type(pickle.loads(data)) is type(job)
    old = pickle.Unpickler(io.BytesIO(b""))
    for name in ("JobContext", "CellsJob", "TrainingJob", "PrepareJob"):
        assert old.find_class("shapebench.sweeps.cluster", name) is getattr(jobs, name)


def test_sweep_file_launcher_block_and_manifest_tolerate_a_cut_line(tmp_path):
    sweep = tmp_path / "s.yaml"
    sweep.write_text("methods: [gauss]\ndatasets: [synthetic]\nlauncher: slurm\n")
    assert load_sweep(sweep).launcher == {"name": "slurm"}
    sweep.write_text("methods: [gauss]\ndatasets: [synthetic]\nlauncher: [slurm]\n")
    with pytest.raises(ConfigError, match="launcher"):
        load_sweep(sweep)
    manifest = tmp_path / "m.jsonl"
    manifest.write_text('{"job_id": "1", "keys": ["a"]}\n{"job_id": "2", "ke')
    assert [j["job_id"] for j in read_manifest(manifest)] == ["1"]


def test_plan_lists_missing_cells_then_nothing_once_the_sweep_ran(shapebench, tmp_path):
    sb = shapebench
    options = ", ".join(o.replace("=", ": ") for o in TINY[1::2])  # the k=v of "-D k=v"
    sweep = tmp_path / "s.yaml"
    sweep.write_text(
        f"name: plan\nmethods: [gauss, {{name: gauss, options: {{sigma: 0.05}}}}]\n"
        f"datasets: [{{name: synthetic, options: {{{options}}}}}]\nsplits: [novel]\n"
        f"contexts: [{TINY_CONTEXTS[1]}]\n"
    )
    res = sb("sweep", str(sweep), "--status")
    assert res.returncode == 0, res.stderr
    assert "4 cells: 4 not submitted" in res.stdout
    res = sb("sweep", str(sweep), "-q")
    assert res.returncode == 0, res.stderr
    assert "sweep progress: 4/4 cells" in res.stdout
    res = sb("sweep", str(sweep), "--status")
    assert "4 cells: 4 finished" in res.stdout
    res = sb("sweep", str(sweep), "--launcher", "submitit-local")
    assert res.returncode == 0 and "nothing to submit" in res.stdout, res.stderr


def test_a_sweep_run_one_seed_at_a_time_fills_the_whole_sweeps_cells(shapebench, tmp_path):
    """`shapebench sweep FILE --seeds 1` runs that seed's cells only, with the whole sweep's keys
    (the whole sweep's --status then counts them finished); a seed the file lacks is one clear
    error naming the file's seeds."""
    sb = shapebench
    options = ", ".join(o.replace("=", ": ") for o in TINY[1::2])
    sweep = tmp_path / "s.yaml"
    sweep.write_text(
        f"name: seeds\nmethods: [gauss]\ndatasets: [{{name: synthetic, options: {{{options}}}}}]\n"
        f"splits: [novel]\ncontexts: [{TINY_CONTEXTS[1]}]\nseeds: [0, 1]\n"
    )
    res = sb("sweep", str(sweep), "-q", "--seeds", "1")
    assert res.returncode == 0, res.stderr
    assert "sweep progress: 2/2 cells" in res.stdout  # two context sizes
    res = sb("sweep", str(sweep), "--status")
    assert "4 cells: 2 finished, 2 not submitted" in res.stdout, res.stdout
    runs = sb.cell_runs("synthetic-novel")
    assert [r.data.params["seed"] for r in runs] == ["1", "1"]
    res = sb("sweep", str(sweep), "--seeds", "0,2")
    assert res.returncode != 0
    assert "no seed 2" in res.stderr and "its seeds: 0, 1" in res.stderr
    assert "Traceback" not in res.stderr


def test_status_tells_trainings_shipped_weights_serve_from_trainings_to_run(shapebench, tmp_path):
    """MSC's quick reference ships (shapebench/reference_checkpoints), PCN's does not: --status
    must not count installing shipped weights as a training still to run."""
    sweep = tmp_path / "s.yaml"
    sweep.write_text(
        "name: shipped\nmethods: [msc, pcn]\ndatasets: [synthetic]\nsplits: [trained]\n"
        "contexts: [50]\n"
    )
    res = shapebench("sweep", str(sweep), "--status")
    assert res.returncode == 0, res.stderr
    assert "1 trainings missing: train pcn on synthetic seed=0" in res.stdout
    assert "1 trainings served by shipped reference weights" in res.stdout
    assert "train msc on synthetic seed=0" in res.stdout.split("shipped reference weights")[1]


def test_run_through_the_cluster_launcher_computes_the_cells_run_inline_finds(shapebench):
    """`run --launcher submitit-local` logs under the same cell keys as an inline `run`."""
    sb = shapebench
    args = ["run", "-m", "gauss", "-d", "synthetic", *TINY, "--split", "novel", "--contexts", "50"]
    res = sb(*args, "--launcher", "submitit-local", timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "as a sweep of one method" in res.stdout and "1 cells: 1 finished" in res.stdout
    res = sb(*args)
    assert res.returncode == 0, res.stderr
    assert "cached" in res.stdout and " new " not in res.stdout
    assert len(sb.cell_runs("synthetic-novel")) == 1
    res = sb(*args, "--launcher", "slurm", "--checkpoint", str(sb.workspace / "mlflow.db"))
    assert res.returncode == 2 and "--launcher inline" in res.stderr


def test_a_job_rebuilds_the_sweep_narrowed_as_it_was_submitted(tmp_path):
    """Cells travel as indices among the method entries, so a job of `sweep -m msc` must narrow
    the sweep file the same way, or it would run another method's cell."""
    from pathlib import Path

    from shapebench.sweeps.jobs import JobContext
    from shapebench.sweeps.spec import only_methods, sweep_methods

    path = Path(__file__).parents[2] / "configs/sweeps/data-scaling.yaml"
    ctx = JobContext(str(path), None, "", str(tmp_path), str(tmp_path), {}, methods=("msc",))
    rebuilt = sweep_methods(ctx.spec())
    assert rebuilt == sweep_methods(only_methods(load_sweep(path), ["msc"]))
    assert {e.name for e in rebuilt} == {"msc"} and len(rebuilt) == 3
    three = path.with_name("standard.yaml")  # seeds 0, 1 and 2
    ctx = JobContext(str(three), None, "", str(tmp_path), str(tmp_path), {}, seeds=(1,))
    assert ctx.spec().seeds == [1]
