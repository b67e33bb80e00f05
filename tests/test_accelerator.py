"""The acceptance command for accelerators (benchmarks/accelerator.py), run on CPUs at --small:
every row of its tables is measured, none is refused silently, and its JSON holds the figures."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "benchmarks" / "accelerator.py"


def run_script(*arguments: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *arguments], capture_output=True, text=True, cwd=cwd)


@pytest.mark.slow
def test_small_measures_every_row_on_cpus(tmp_path):
    """In the session's compilation cache (conftest.py): the programs other tests compiled
    (the tasks' episode starts) are loaded, not compiled again. A budget no loaded machine
    runs out of: every rollout row must be measured, none skipped for time."""
    out = tmp_path / "accelerator.json"
    cache = os.environ["JAX_COMPILATION_CACHE_DIR"]
    result = run_script("--small", "--out", str(out), "--cache", cache, "--budget", "3600", cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr[-3000:]
    table = result.stdout
    for part in ("walker2d, 1 run", "halfcheetah, 1 run", "ant_omni, 1 run", "ant_omni, 8 runs"):
        row = next(line for line in table.splitlines() if line.startswith(f"| {part} |"))
        assert row.rstrip().endswith("| ok |"), row
    assert "Scaling over runs: 8 ant_omni runs together" in table
    assert "the --small settings (not the paper's)" in table

    figures = json.loads(out.read_text())
    assert figures["small"] and figures["errors"] == 0
    assert figures["devices"][0]["platform"] == "cpu" and figures["environment"]["devices"]["platform"] == "cpu"
    for part in figures["runner"]:
        assert part["status"] == "ok" and part["evaluations_per_second"] > 0
        assert part["estimated_bytes"] > 0 and part["peak_bytes"] > 0
        assert part["config"]["batch_size"] == 16
        if part["runs"] == 1:  # a full archive re-scored, every cell
            assert part["full_reevaluation_seconds"] > 0 and 1 <= part["full_reevaluation_cells"] <= 32
    assert [row["task"] for row in figures["reproduce"]] == ["walker2d", "halfcheetah", "ant_omni"]
    for row in figures["reproduce"]:
        assert row["status"] == "ok" and row["runs"] == 80 and row["device_hours"] > 0
        assert row["fits"].startswith("yes")
    assert {row["scaled_from_runs"] for row in figures["reproduce"]} == {1, 8}
    rollouts = figures["rollouts"]
    expected = [(task, physics) for task in ("walker2d", "ant_omni") for physics in ("spring", "mjx")]
    assert [(row["task"], row["physics"], row["batch_size"]) for row in rollouts] == [
        (task, physics, batch) for task, physics in expected for batch in (16, 32)
    ]
    assert all(row["status"] == "ok" and row["steps_per_second"] > 0 for row in rollouts)
    for row in rollouts:
        assert f"| {row['task']} | {row['physics']} | 10 | {row['batch_size']} |" in table


@pytest.mark.parametrize(
    ("arguments", "words"),
    [
        (("--budget", "0"), "--budget 0.0: give the seconds"),
        (("--out", "no/such/folder/figures.json"), "its folder no/such/folder does not exist"),
    ],
)
def test_bad_options_are_refused_before_any_work(tmp_path, arguments, words):
    result = run_script(*arguments, cwd=tmp_path)
    assert result.returncode == 2 and words in result.stderr
    assert "Traceback" not in result.stderr
