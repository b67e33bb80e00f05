"""Paced schedules trained (issue 45): the body a run trains in follows its clock, a phase
end at which the clock stands still keeps the archive bit for bit (a `hold` row, nothing
re-scored), a condition that never holds ends on the final body from the deadline, a paced
run in a sweep is the same run alone, and a paced run or sweep killed with SIGKILL resumes
bit for bit. At the run-level tests' size (small_runs), so programs are shared."""

from __future__ import annotations

import csv
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from small_runs import FLAGS

import smol_dsl
from smol_dsl.cli import main
from smol_dsl.rundir.snapshots import END, START, read_snapshots

pytestmark = pytest.mark.slow  # every test trains walker2d

CURVE = "0% .. 90%: linear 1.5 -> 1 decreasing\n90% .. 100%: tail\n"
EVERY_OTHER = 'name "every-other"\npace when waited >= 2 within 3 phases\n' + CURVE
"""Moves on every second phase end, whatever the metrics: holds at known boundaries."""
NEVER = 'name "never"\npace when max_fitness > 1e9 within 3 phases\n' + CURVE
"""Can hold (max_fitness is any number), never does at this size: moves on at the bound only."""
RECOVERED = 'name "recovered"\npace when coverage >= before(coverage) within 3 phases\n' + CURVE
"""Moves on once coverage is back to what it was before the last move: depends on the run."""


def rows_of(directory: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(open(directory / "metrics.csv")))


def phase_starts(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    """The first row of every phase: init, or the boundary's reevaluate or hold row."""
    return [row for row in rows if row["event"] in ("init", "reevaluate", "hold")]


@pytest.fixture(scope="module")
def schedules(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("paced-schedules")
    paths = {}
    for name, text in (("every-other", EVERY_OTHER), ("never", NEVER), ("recovered", RECOVERED)):
        paths[name] = folder / f"{name}.sched"
        paths[name].write_text(text)
    return paths


@pytest.fixture(scope="module")
def paced_runs(schedules, tmp_path_factory) -> dict[str, Path]:
    """Each paced schedule trained alone through the CLI, in this process."""
    folder = tmp_path_factory.mktemp("paced-runs")
    outs = {}
    for name, path in schedules.items():
        outs[name] = folder / name
        assert main(["run", "walker2d", str(path), *FLAGS, "--no-progress", "--out", str(outs[name])]) == 0
    return outs


@pytest.fixture(scope="module")
def paced_sweep(schedules, tmp_path_factory) -> Path:
    """every-other, recovered and SMOL (open loop) in one sweep of seed 0."""
    out = tmp_path_factory.mktemp("paced-sweep") / "sweep"
    args = ["sweep", "walker2d", str(schedules["every-other"]), str(schedules["recovered"]), "smol", *FLAGS]
    assert main([*args, "--seeds", "1", "--no-progress", "--out", str(out)]) == 0
    return out


def test_the_body_follows_the_clock_and_a_held_phase_keeps_its_archive_bit_for_bit(paced_runs):
    out = paced_runs["every-other"]
    rows = rows_of(out)
    starts = phase_starts(rows)
    assert [row["event"] for row in starts] == ["init"] + ["hold", "reevaluate"] * 4 + ["reevaluate"]
    assert [int(row["development"]) for row in starts] == [0, 0, 1, 1, 2, 2, 3, 3, 4, 9]
    values = np.asarray(smol_dsl.parse(EVERY_OTHER).phase_alphas(10))
    for row in rows:  # every row's body is the curve's at its development step
        assert np.float32(row["alpha"]) == values[int(row["development"])], row
    for row in rows:
        if row["event"] == "hold":
            assert all(row[name] == "" for name in ("reevaluated", "kept", "moved", "collided", "died")), row
    snapshots = read_snapshots(out)
    assert all(s.body is not None and s.body[0] == np.float32(starts[s.phase]["alpha"]) for s in snapshots)
    for row in starts[1:]:
        end = next(s for s in snapshots if s.moment == END and s.phase == int(row["phase"]) - 1)
        start = next(s for s in snapshots if s.moment == START and s.phase == int(row["phase"]))
        held = row["event"] == "hold"
        assert held == (
            np.array_equal(end.fitnesses, start.fitnesses) and np.array_equal(end.descriptors, start.descriptors)
        ), row
    before_hold = [rows[i - 1] for i, row in enumerate(rows) if row["event"] == "hold"]
    holds = [row for row in rows if row["event"] == "hold"]
    for held, previous in zip(holds, before_hold, strict=True):  # nothing re-scored: the same scores
        assert [held[name] for name in ("coverage", "max_fitness", "qd_score", "evaluations", "reevaluations")] == [
            previous[name] for name in ("coverage", "max_fitness", "qd_score", "evaluations", "reevaluations")
        ]


def test_a_run_whose_condition_never_holds_ends_on_the_final_body_from_the_deadline(paced_runs):
    starts = phase_starts(rows_of(paced_runs["never"]))
    assert [int(row["development"]) for row in starts] == [0, 0, 0, 1, 1, 1, 2, 2, 2, 9]
    assert float(starts[-1]["alpha"]) == 1.0 and float(starts[-2]["alpha"]) > 1.3  # the jump into the tail
    certificate = (paced_runs["never"] / "certificate.txt").read_text()
    assert "where development has not finished, the rest of the curve is skipped" in certificate


def assert_same_rows(ours: Path, theirs: Path) -> None:
    """The same run in another program layout (a sweep's, a single run's): every event,
    phase, body, development step and count alike, scores equal to float32 rounding (XLA
    compiles a rollout differently inside another program; test_sweep compares so too)."""
    mine, reference = rows_of(ours), rows_of(theirs)
    assert len(mine) == len(reference)
    scores = ("coverage", "max_fitness", "qd_score")
    for a, b in zip(mine, reference, strict=True):
        assert {k: v for k, v in a.items() if k not in scores} == {k: v for k, v in b.items() if k not in scores}
        for name in scores:
            assert float(a[name]) == pytest.approx(float(b[name]), rel=1e-5)


def test_a_paced_run_in_a_sweep_is_the_same_run_alone(paced_runs, paced_sweep, tmp_path):
    for name in ("every-other", "recovered"):
        assert_same_rows(paced_sweep / f"walker2d-{name}-seed0", paced_runs[name])
    alone = tmp_path / "smol"
    assert main(["run", "walker2d", "smol", *FLAGS, "--no-progress", "--out", str(alone)]) == 0
    assert_same_rows(paced_sweep / "walker2d-smol-seed0", alone)  # open loop, beside paced runs
    assert read_snapshots(alone)[0].body is None  # an open-loop run's phases.npz as before: no bodies
    events = [{row["event"] for row in rows_of(path)} for path in paced_sweep.iterdir() if path.is_dir()]
    assert any("hold" in e for e in events) and any("hold" not in e for e in events)  # mixed boundaries


def _killed_then_resumed(args: list[str], out: Path, cwd: Path, boundaries: int) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "smol_dsl.cli", *args, "--no-progress", "--out", str(out)]
    killed = subprocess.Popen(command, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 600
    while time.time() < deadline:  # kill once a few boundaries are checkpointed
        texts = [path.read_text() for path in out.rglob("metrics.csv")]
        if texts and min(text.count("reevaluate") + text.count("hold") for text in texts) >= boundaries:
            break
        time.sleep(0.05)
    killed.send_signal(signal.SIGKILL)
    killed.wait()
    return subprocess.run([*command, "--resume"], cwd=cwd, capture_output=True, text=True, timeout=600)


def _same_runs(ours: Path, theirs: Path) -> None:
    for name in ("metrics.csv", "phases.npz"):
        assert (ours / name).read_bytes() == (theirs / name).read_bytes(), name
    mine, reference = np.load(ours / "archive.npz"), np.load(theirs / "archive.npz")
    for name in reference.files:
        np.testing.assert_array_equal(mine[name], reference[name])


def test_kill_9_then_resume_of_a_paced_run_and_sweep_equals_uninterrupted(schedules, paced_runs, paced_sweep, tmp_path):
    resumed = _killed_then_resumed(
        ["run", "walker2d", str(schedules["recovered"]), *FLAGS], tmp_path / "run", tmp_path, 3
    )
    assert resumed.returncode == 0, resumed.stderr
    _same_runs(tmp_path / "run", paced_runs["recovered"])
    args = ["sweep", "walker2d", str(schedules["every-other"]), str(schedules["recovered"]), "smol", *FLAGS]
    resumed = _killed_then_resumed([*args, "--seeds", "1"], tmp_path / "sweep", tmp_path, 3)
    assert resumed.returncode == 0, resumed.stderr
    for run in (path for path in paced_sweep.iterdir() if path.is_dir()):
        _same_runs(tmp_path / "sweep" / run.name, run)


def test_report_plot_and_explore_show_the_bodies_a_paced_run_reached(paced_runs, paced_sweep, tmp_path, capsys):
    """report: bodies.png beside the other figures, the re-evaluation figure drawn with the
    held boundaries left out; plot: the run's own steps over the schedule's envelope;
    explore: the run's alpha per row, as it trained; robustness's final body: the last."""
    from smol_dsl.results.explorer import Explorer
    from smol_dsl.rundir import read_run

    out = tmp_path / "report"
    assert main(["report", str(paced_sweep), "--no-gaits", "-o", str(out)]) == 0
    assert {"bodies.png", "bodies.pdf", "reevaluation.png", "table.md"} <= {path.name for path in out.iterdir()}
    assert "bodies.png" in (out / "index.html").read_text()
    scores = {row["schedule"]: row for row in csv.DictReader(open(out / "scores.csv"))}
    rows = rows_of(paced_sweep / "walker2d-every-other-seed0")
    assert int(scores["every-other"]["body changes"]) == 5 and int(scores["SMOL"]["body changes"]) == 9
    last_of_phase_8 = [row for row in rows if row["phase"] == "8" and row["event"] == "train"][-1]
    assert float(scores["every-other"]["coverage before the tail"]) == float(last_of_phase_8["coverage"])
    figure = tmp_path / "paced.png"
    assert main(["plot", "smol-paced", str(paced_runs["every-other"]), "-o", str(figure)]) == 0
    assert figure.stat().st_size > 10_000
    assert "every-other (every-other); 10 phases" in capsys.readouterr().out
    explorer = Explorer([paced_runs["every-other"]], replay=None, cache=tmp_path / "cache")
    data = explorer.run_data(0)
    rows = rows_of(paced_runs["every-other"])
    assert data["alpha"] == [float(row["alpha"]) for row in rows]
    record = read_run(paced_runs["every-other"])
    bodies = record.phase_bodies()[:, 0]
    starts = phase_starts(rows)
    assert bodies.tolist() == [np.float32(row["alpha"]) for row in starts] and bodies[-1] == 1.0
