"""The speed benchmarks (benchmarks/*.py but accelerator.py, which test_accelerator runs), each
run as a subprocess at a tiny size: it ends well and prints, as a number, every figure its
docstring names. What the figures say about speed is never checked (the tests time nothing).

The sizes are the run-level tests' (tests/small_runs.py), so that in a full session a
benchmark loads from the session's compilation cache (conftest.py) the programs other tests
compiled: the subprocesses inherit its environment, two CPU devices included."""

from __future__ import annotations

import ast
import math
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # every benchmark compiles Brax physics

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


def run_benchmark(script: str, *arguments: str, cwd: Path) -> tuple[list[str], dict[str, float]]:
    """Run benchmarks/`script` in `cwd`: its output lines, and the number each `name: value`
    line gives (the first word of its value) by name; fails on a non-zero exit. Brax's
    imports may print lines of their own ("Failed to import warp: ..."), which are no
    figures: no test expects its lines at set places."""
    command = [sys.executable, str(BENCHMARKS / script), *arguments]
    result = subprocess.run(command, capture_output=True, text=True, cwd=cwd, timeout=1800)
    assert result.returncode == 0, result.stdout + result.stderr[-3000:]
    lines = result.stdout.splitlines()
    figures = {}
    for line in lines:
        name, colon, value = line.partition(": ")
        if colon and name.isidentifier():
            figures[name] = float(value.split()[0])
    return lines, figures


def documented(script: str, names: list[str]) -> list[str]:
    """`names`, each checked to be named in the script's docstring (kept in step with it)."""
    docstring = ast.get_docstring(ast.parse((BENCHMARKS / script).read_text()))
    assert docstring is not None
    assert [name for name in names if name not in docstring] == []
    return names


def assert_figures(figures: dict[str, float], names: list[str]) -> None:
    """Every one of `names` printed, and every figure printed a finite number."""
    assert [name for name in names if name not in figures] == [], sorted(figures)
    assert all(math.isfinite(value) for value in figures.values()), figures


def test_sweep_throughput_small(tmp_path: Path) -> None:
    """Four runs of 10 phases (SMOL's tail allows no fewer) at the tests' size: sequential,
    swept on two devices and on one, and one run each way."""
    lines, figures = run_benchmark("sweep_throughput.py", "--small", cwd=tmp_path)
    header = "# walker2d, 4 runs of 208 evaluations (batch 16, 20-step episodes, 10 phases); 2 cpu device(s)"
    assert any(line.startswith(header) for line in lines), lines
    ratios = ["batched_over_sequential", "batched_one_device_over_sequential", "two_devices_over_one"]
    ratios += ["one_run_two_devices_over_one"]
    seconds = ["sequential_s", "sweep_s", "sweep_one_device_s", "one_run_one_device_s", "one_run_two_devices_s"]
    assert_figures(figures, documented("sweep_throughput.py", ratios) + seconds)
    assert all(figures[name] > 0 for name in ratios + seconds)
    timed = [line for line in lines if line.split(":")[0] in seconds]
    assert len(timed) == len(seconds) and all(line.endswith(" training evals/s)") for line in timed)


def test_runner_throughput_small(tmp_path: Path) -> None:
    """Every timed program measured, and a three-channel run of 10 and of 20 phases
    compiling (or loading) as many programs: each body is a traced input."""
    lines, figures = run_benchmark("runner_throughput.py", "--small", cwd=tmp_path)
    assert "# walker2d, batch 16, 20-step episodes, 2 cpu device(s)" in lines, lines
    ratios = ["run_all_devices_over_one_device", "overhead_ratio", "vs_qdax_ratio", "vs_qdax_same_options_ratio"]
    ratios += ["reeval_10pct_over_100pct"]
    compiles = ["compiles_10_phases", "compiles_20_phases"]
    rates = ["raw_rollout_evals_per_s", "run_one_device_evals_per_s", "run_all_devices_evals_per_s", "qdax_evals_per_s"]
    rates += ["qdax_same_options_evals_per_s", "reeval_100pct_s", "reeval_10pct_s"]
    assert_figures(figures, documented("runner_throughput.py", ratios + compiles) + rates)
    assert all(figures[name] > 0 for name in ratios + rates)
    assert figures["compiles_10_phases"] == figures["compiles_20_phases"] > 0


def test_checkpoint_stall_tiny(tmp_path: Path) -> None:
    """Two archives of 32 cells (20 MB): each writer timed, and its folder under the working
    directory removed."""
    lines, figures = run_benchmark("checkpoint_stall.py", "--runs", "2", "--cells", "32", cwd=tmp_path)
    assert {"devices: 2 cpu", "checkpoint_gb: 0.02 (2 runs x 10 MB)"} <= set(lines), lines
    names = ["async_npz_stall_over_sync", "async_npz_total_over_sync", "sync_npz_stall_s", "async_npz_stall_s"]
    names += ["async_npz_total_s", "async_npz_compute_during_write", "sync_npz_gb_per_s"]
    try:
        import orbax.checkpoint  # noqa: F401  (Brax installs it; the script times it when it is there)
    except ImportError:
        pass
    else:
        names += ["orbax_async_stall_over_sync", "orbax_async_stall_s", "orbax_async_total_s"]
        names += ["orbax_async_compute_during_write"]
    assert_figures(figures, names)
    documented("checkpoint_stall.py", ["_stall_over_sync", "sync_npz", "async_npz", "orbax_async"])
    assert all(figures[name] > 0 for name in names)
    assert list(tmp_path.iterdir()) == []


def test_factor_ranges_tiny(tmp_path: Path) -> None:
    """walker2d's four kinds over 20-step episodes: each range a low and a high factor around 1,
    found by trials printed one a line."""
    lines, figures = run_benchmark("factor_ranges.py", "walker2d", "--episode-length", "20", cwd=tmp_path)
    assert "walker2d on spring: 16 random policies, 20 steps" in lines, lines
    kinds = ["gear", "mass", "friction", "gravity"]
    ranges = {}
    for line in lines:
        name, _, value = line.partition(": ")
        if name.startswith("finite_range_"):
            low, dots, high = value.split()
            assert dots == ".."
            ranges[name.removeprefix("finite_range_")] = (float(low), float(high))
    assert list(ranges) == kinds
    assert all(0 < low <= 1 <= high < math.inf for low, high in ranges.values()), ranges
    trials = [line for line in lines if line.startswith("  ")]
    assert trials and all(line.split()[0] in kinds and line.endswith(" finite") for line in trials)
    assert_figures(figures, ["seconds"])
    assert "`TaskSpec.factor_ranges`" in ast.get_docstring(ast.parse((BENCHMARKS / "factor_ranges.py").read_text()))


def test_physics_throughput_small(tmp_path: Path) -> None:
    """walker2d on spring and on MJX, side by side at the tests' size: every figure printed."""
    lines, figures = run_benchmark("physics_throughput.py", "--small", "--tasks", "walker2d", cwd=tmp_path)
    assert "# walker2d, batch 16, 20-step episodes, 2 cpu device(s)" in lines
    names = [
        f"walker2d_{name}"
        for name in (
            *(f"{physics}_{figure}" for physics in ("spring", "mjx") for figure in ("compile_s", "raw_steps_per_s")),
            *(f"{physics}_engine_evals_per_s" for physics in ("spring", "mjx")),
            "mjx_over_spring_raw",
            "mjx_over_spring_engine",
        )
    ]
    assert_figures(figures, names)
    documented("physics_throughput.py", ["TASK_PHYSICS_raw_steps_per_s", "TASK_mjx_over_spring_raw"])
