"""The suite's fork server (tests/cli_fork.py) runs a command as a new interpreter would."""

from __future__ import annotations

import re

import pytest
from conftest import TINY, Shapebench

#: MLflow's own log lines (a timestamp, then INFO): the first command of a store creates it.
_MLFLOW_LOG = re.compile(r"^\d{4}/\d\d/\d\d \d\d:\d\d:\d\d INFO mlflow\..*\n", re.MULTILINE)


@pytest.mark.slow  # runs the CLI in subprocesses
def test_a_forked_command_answers_like_a_new_interpreter(tmp_path, data_cache):
    forked_ws, fresh_ws = tmp_path / "forked", tmp_path / "fresh"
    forked_ws.mkdir()
    fresh_ws.mkdir()
    forked_sb, fresh_sb = Shapebench(forked_ws, data_cache), Shapebench(fresh_ws, data_cache)
    for args in (
        ("run", "-m", "nope", "-d", "synthetic"),  # a usage error: exit 2, one line on stderr
        ("run", "-m", "gauss", "-d", "synthetic", *TINY, "--contexts", "50", "-q"),
        ("runs", "--json"),
    ):
        forked, fresh = forked_sb(*args), fresh_sb(*args, fresh=True)
        if args[1:3] == ("-m", "nope"):
            assert forked.returncode == 2 and "unknown method 'nope'" in forked.stderr
        assert forked.returncode == fresh.returncode, (args, forked.stderr, fresh.stderr)
        assert _MLFLOW_LOG.sub("", forked.stderr) == _MLFLOW_LOG.sub("", fresh.stderr), args
        scores = re.compile(r"\d+\.\d+ ± \d+\.\d+")
        if "gauss" in args:  # the same cells, with the same scores
            assert scores.findall(forked.stdout) == scores.findall(fresh.stdout)
            assert len(scores.findall(forked.stdout)) == 2  # trained and novel
        elif args[0] == "runs":
            assert forked.stdout.count("\n") == fresh.stdout.count("\n") > 0
