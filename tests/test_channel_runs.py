"""Runs under multi-channel schedules: every channel's value traced (one compilation for any
values and phases), metrics.csv and the progress bar with a column per channel, sweeps of
schedules with different channels, and `report` refusing schedules whose final bodies differ."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import jax
import numpy as np
import pytest
import small_runs

import smol_dsl
from smol_dsl.language.channels import GEAR, Channel
from smol_dsl.results.runs import ReportError, load_runs
from smol_dsl.runner import engine as engine_module
from smol_dsl.runner import run_experiment
from smol_dsl.runner.engine import Engine, shared_engine
from smol_dsl.runner.progress import ProgressBar

pytestmark = pytest.mark.slow  # every test here compiles Brax physics

THREE_CHANNELS = Path(__file__).resolve().parent.parent / "examples" / "three-channels.sched"


def small_config(**overrides):
    """The tests' one size (small_runs), over 20 phases."""
    return small_runs.small_config(**{"evaluations": 16 * 21, "num_phases": 20, **overrides})


@pytest.fixture(scope="module")
def task():
    return small_runs.small_task()


@pytest.fixture(scope="module")
def three_channel_run(task, tmp_path_factory):
    out = tmp_path_factory.mktemp("channels") / "three"
    return run_experiment(task, smol_dsl.load(THREE_CHANNELS), small_config(), out_dir=out)


def spy(method, calls):
    """`method`, recording the object it is called on in `calls`."""

    def recorded(self, *args, **kwargs):
        calls.append(self)
        return method(self, *args, **kwargs)

    return recorded


def test_every_channel_is_a_traced_input_one_compilation_for_all_phases(three_channel_run, task, monkeypatch):
    schedule = smol_dsl.load(THREE_CHANNELS)
    assert three_channel_run.channels == (GEAR, Channel("mass"), Channel("friction"))
    values = three_channel_run.bodies
    assert values.shape == (small_config().num_phases, 3)
    assert len({tuple(row) for row in values}) > 10  # the body changes from phase to phase
    engine = shared_engine(task, three_channel_run.config, tuple(jax.local_devices()), 1, 1, schedule.channels)
    programs = {part: getattr(engine, part)._cache_size() for part in ("_ask", "_scores", "_tell", "_pick", "_insert")}
    assert programs["_scores"] == 1  # one scoring program for every generation and re-evaluation
    # another run of these channels, with 11 phases of other values and another seed: the same
    # engine (no engine is built), and no new program in it
    built = engine_module._engine.cache_info()
    used = []
    monkeypatch.setattr(Engine, "step", spy(Engine.step, used))
    again = run_experiment(task, schedule, small_config(num_phases=11, seed=9))
    assert again.bodies.shape == (11, 3) and not np.array_equal(again.bodies[:10], values)
    assert used and all(other is engine for other in used)
    assert engine_module._engine.cache_info().misses == built.misses
    assert {part: getattr(engine, part)._cache_size() for part in programs} == programs


def test_metrics_csv_has_a_column_per_channel(three_channel_run):
    with open(three_channel_run.out_dir / "metrics.csv", newline="") as file:
        rows = list(csv.DictReader(file))
    header = list(rows[0])
    assert header[:5] == ["generation", "phase", "alpha", "mass", "friction"]
    values = three_channel_run.bodies
    for row in rows:
        phase = int(row["phase"])
        assert [float(row["alpha"]), float(row["mass"]), float(row["friction"])] == pytest.approx(
            values[phase].tolist(), rel=1e-7
        )
    certificate = json.loads((three_channel_run.out_dir / "certificate.json").read_text())
    assert set(certificate["channels"]) == {"gear", "mass", "friction"}
    text = (three_channel_run.out_dir / "certificate.txt").read_text()
    assert "channel mass" in text and "channel friction" in text


def test_progress_bar_shows_every_channel(three_channel_run, capsys):
    bar = ProgressBar(three_channel_run.config)
    bar.update([three_channel_run.metrics[-1]], three_channel_run.config.generations)
    bar.close()
    shown = capsys.readouterr().err
    assert "alpha 1.000 mass 1.000 friction 1.000" in shown


def test_a_sweep_trains_schedules_of_different_channels_together(mixed_sweep):
    _, config, results = mixed_sweep
    vanilla, growth, damage = results
    assert vanilla.channels == (GEAR,)
    assert set(growth.channels) == {GEAR, Channel("mass")}
    assert damage.channels == (Channel("gear", ("left_leg",)),)
    headers = {}
    for result in results:
        with open(result.out_dir / "metrics.csv", newline="") as file:
            headers[result.out_dir.name] = next(csv.reader(file))
    assert "mass" not in headers["walker2d-vanilla-seed0"]
    assert "mass" in headers["walker2d-growth-seed0"]
    assert "gear[left_leg]" in headers["walker2d-leg-damage-seed0"]
    final = smol_dsl.load("leg-damage").final_body[damage.channels[0]]
    assert damage.metrics[-1]["gear[left_leg]"] == pytest.approx(final)
    # vanilla's run in the mixed program follows the same algorithm as alone (mass 1 is the standard body)
    alone = run_experiment("walker2d", smol_dsl.load("vanilla"), config)
    np.testing.assert_array_equal(vanilla.alphas, alone.alphas)
    a, b = np.asarray(vanilla.repertoire.fitnesses), np.asarray(alone.repertoire.fitnesses)
    np.testing.assert_array_equal(a > -np.inf, b > -np.inf)
    np.testing.assert_allclose(a, b, rtol=1e-5)


def test_report_refuses_schedules_whose_final_bodies_differ(mixed_sweep):
    out, _, results = mixed_sweep
    with pytest.raises(ReportError, match=r"thigh_left_joint.s gear factor ends at 0\.5 in Leg damage .* and at 1 in"):
        load_runs([out])
    same_body = [result.out_dir for result in results if "leg-damage" not in result.out_dir.name]
    assert list(load_runs(same_body)) == ["Vanilla MAP-Elites", "Growth"]
