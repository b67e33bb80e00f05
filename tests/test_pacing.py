"""Pacing (`pace when CONDITION within N phases`): the clause's parsing, proof and errors,
the decision as a pure function of a run's metrics, and the certificate every realised
trajectory keeps, whatever the metrics do (hypothesis)."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import smol_dsl
from smol_dsl.cli import main
from smol_dsl.errors import ScheduleError
from smol_dsl.language.expressions import PACING_NAMES
from smol_dsl.language.pacing import METRICS, NAMES, PaceState

SMOL_PACED = """\
name "SMOL-paced"
pace when coverage >= 90% * before(coverage) within 3 phases
0% .. 90%: linear 1.5 -> 1 decreasing
90% .. 100%: tail
"""

TWO_CLOCKS = """\
pace when coverage >= before(coverage) within 2 phases
channel gear
0% .. 90%: linear 1.5 -> 1 decreasing
90% .. 100%: tail
channel mass
pace when waited >= 2 and max_fitness > after(max_fitness) within 4 phases
0% .. 80%: linear 0.5 -> 1 increasing
80% .. 100%: tail
channel friction
0% .. 50%: constant 0.8
50% .. 100%: tail
"""


def metrics(coverage: float, max_fitness: float = 0.0, qd_score: float = 0.0) -> dict[str, float]:
    return {"coverage": coverage, "max_fitness": max_fitness, "qd_score": qd_score}


def realised(
    schedule: smol_dsl.Schedule, num_phases: int, history: list[dict[str, float]], after: list[dict[str, float]]
):
    """The development per phase and each channel's realised values, for metrics at every
    phase's end (`history`) and after every boundary's re-evaluation (`after`), through
    `Pacing.initial`, `decide` and `settle` as the runner calls them."""
    pacing = schedule.pacing
    assert pacing is not None
    values = np.asarray(schedule.phase_values(num_phases))
    decide = _jitted_decide(pacing, schedule.tail_phase(num_phases))
    state = pacing.initial(after[0])
    developments, bodies, waits = [], [], []
    for phase in range(num_phases):
        indices = np.asarray(schedule.phase_indices(state.development, phase, num_phases))
        developments.append(np.asarray(state.development))
        bodies.append(values[indices, np.arange(values.shape[1])])
        waits.append(np.asarray(state.waited))
        if phase + 1 < num_phases:
            decided = decide(state, history[phase], phase)
            state = pacing.settle(state, decided, after[phase + 1])
    return np.stack(developments), np.stack(bodies), np.stack(waits)


@functools.lru_cache(maxsize=8)
def _jitted_decide(pacing, tail_phase: int):
    """The decision jitted once per pacing (equal pacings parsed again share it)."""
    return jax.jit(lambda state, m, phase: pacing.decide(state, m, phase, tail_phase))


# ---------------------------------------------------------------- the language


def test_a_paced_file_checks_and_its_certificate_says_what_pacing_changes():
    schedule = smol_dsl.parse(SMOL_PACED)
    assert schedule.is_paced and not smol_dsl.load("smol").is_paced
    text = schedule.certificates_text()
    assert "pace (gear): moves on when coverage >= 90% * before(coverage), within 3 phases (line 2)" in text
    assert "a jump of at most 0.5 (from [1, 1.5]): proven" in text
    envelope = schedule.envelope_text(20).splitlines()
    assert envelope[0] == "envelope over 20 phases (tail from phase 18):"
    assert envelope[2].split()[:4] == ["0", "0", "1.5", ".."]
    assert envelope[-3].split()[:2] == ["18", "18"] and envelope[-1].endswith("0.3611")


def test_check_prints_the_envelope_over_the_phases_asked(tmp_path, capsys):
    path = tmp_path / "paced.sched"
    path.write_text(SMOL_PACED)
    assert main(["check", str(path), "--phases", "10"]) == 0
    out = capsys.readouterr().out
    assert "envelope over 10 phases (tail from phase 9):" in out
    assert main(["check", str(path), "--phases", "5"]) == 2
    assert "use --phases 10 or more" in capsys.readouterr().err


def test_the_pacing_names_are_built_in():
    assert set(PACING_NAMES) == set(NAMES)


@pytest.mark.parametrize(
    "line, message, hint",
    [
        ("pace when coverage >= 50 within 3 phases", "can never hold", "write 50% for half the cells"),
        ("pace when coverage >= 0 within 3 phases", "always holds", "can fail"),
        ("pace when waited >= 3 within 3 phases", "can never hold", "waited runs from 1 to 2"),
        ("pace when coverage >= coverage within 3 phases", "always holds", "can fail"),
        ("pace when coverag > 50% within 3 phases", "unknown name `coverag` in a pace condition", "`coverage`"),
        ("pace when before > 50% within 3 phases", "unknown name `before`", "`before(coverage)`"),
        ("pace when before(waited) > 1 within 3 phases", "`before(...)` takes one metric", "before(max_fitness)"),
        ("pace when log(coverage) > -1 within 3 phases", "`log` is not evaluated in a pace condition", "min"),
        ("pace when coverage ** 0.5 > 50% within 3 phases", "is not a whole power", "whole powers"),
        ("pace when coverage > 50% within 0 phases", "the pace bound is 0", "whole number from 2"),
        ("pace when coverage > 50% within 1 phases", "the pace bound is 1", "delete the line"),
        ("pace when coverage > 50% within 2.5 phases", "the pace bound is 2.5", "whole number"),
        ("pace when coverage > 50% within 5000 phases", "the pace bound is 5000", "whole number"),
        ("pace when coverage > 50%", "", ""),
    ],
)
def test_bad_pacing_is_one_located_error(line, message, hint):
    text = SMOL_PACED.replace(SMOL_PACED.splitlines()[1], line)
    with pytest.raises(ScheduleError) as raised:
        smol_dsl.parse(text)
    error = raised.value
    assert error.line == 2 and message in error.message and hint in (error.hint or "")


def test_a_paced_random_segment_a_let_named_as_a_metric_and_a_second_pace_line_are_refused():
    random = "pace when coverage > 50% within 3 phases\n0% .. 90%: random 0.5 .. 1.5 every 10%\n90% .. 100%: tail\n"
    with pytest.raises(ScheduleError, match="is paced and has a `random` segment") as raised:
        smol_dsl.parse(random)
    assert raised.value.line == 1 and "line 2" in raised.value.hint
    with pytest.raises(ScheduleError, match="`coverage` is a built-in name"):
        smol_dsl.parse("let coverage = 1\n" + SMOL_PACED)
    with pytest.raises(ScheduleError, match="`pace` is given twice") as raised:
        smol_dsl.parse(SMOL_PACED + "pace when coverage > 50% within 2 phases\n")
    assert raised.value.line == 5


def test_bad_pacing_through_the_cli_exits_2_without_a_traceback(tmp_path, capsys):
    path = tmp_path / "bad.sched"
    path.write_text(SMOL_PACED.replace("90% * before(coverage)", "90"))
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}:2:11: error: the pace condition can never hold" in err and "Traceback" not in err


def test_a_file_level_pace_paces_every_channel_without_its_own():
    schedule = smol_dsl.parse(TWO_CLOCKS)
    assert [schedule.clock_of(c) for c in schedule.channels] == [0, 1, 0]
    assert schedule.pacing is not None and [clock.within for clock in schedule.pacing.clocks] == [2, 4]
    assert schedule.clock_of("gear[left_leg]") is None
    text = schedule.certificates_text()
    assert "pace (gear, friction): moves on when coverage >= before(coverage), within 2 phases (line 1)" in text
    assert "pace (mass): moves on when waited >= 2 and max_fitness > after(max_fitness), within 4 phases" in text
    unpaced = TWO_CLOCKS.replace(TWO_CLOCKS.splitlines()[0] + "\n", "")
    schedule = smol_dsl.parse(unpaced)
    assert [schedule.clock_of(c) for c in schedule.channels] == [None, 0, None]


# ---------------------------------------------------------------- the decision


def test_development_moves_on_when_the_condition_holds_and_at_the_bound_otherwise():
    schedule = smol_dsl.parse(SMOL_PACED)
    pacing = schedule.pacing
    state = pacing.initial(metrics(0.5))
    assert state.development.tolist() == [0] and state.before.tolist() == [[0.5, 0.0, 0.0]]
    held = pacing.decide(state, metrics(0.44), 0, 18)  # 0.44 < 90% of 0.5: held
    assert held.development.tolist() == [0] and held.waited.tolist() == [1]
    moved = pacing.decide(state, metrics(0.46), 0, 18)
    assert moved.development.tolist() == [1] and moved.waited.tolist() == [0]
    assert np.allclose(moved.before, [[0.46, 0, 0]])
    settled = pacing.settle(state, moved, metrics(0.3))
    assert np.allclose(settled.after, [[0.3, 0, 0]]) and np.allclose(
        pacing.settle(state, held, metrics(0.3)).after, [[0.5, 0, 0]]
    )
    twice = pacing.decide(held, metrics(0.1), 1, 18)
    assert twice.development.tolist() == [0] and twice.waited.tolist() == [2]
    forced = pacing.decide(twice, metrics(0.1), 2, 18)  # held 3 phases: moves on whatever the metrics
    assert forced.development.tolist() == [1]
    deadline = pacing.decide(twice, metrics(0.1), 17, 18)  # phase 18 is the tail: the final body
    assert deadline.development.tolist() == [18]


def test_a_run_whose_condition_never_holds_steps_at_the_bound_and_ends_on_the_final_body():
    schedule = smol_dsl.parse(SMOL_PACED)
    falling = [metrics(0.5 * 0.8 ** (phase + 1)) for phase in range(20)]  # never back to 90% of before
    developments, bodies, _ = realised(schedule, 20, falling, [metrics(0.5), *falling[:-1]])
    assert developments[:, 0].tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3, 3, 4, 4, 4, 5, 5, 5, 18, 19]
    values = np.asarray(schedule.phase_alphas(20))
    assert bodies[:18, 0].tolist() == values[developments[:18, 0]].tolist()
    assert bodies[18:, 0].tolist() == [1.0, 1.0]
    flat = [metrics(0.5)] * 20  # always back to what it was: the budget's pace
    developments, _, _ = realised(schedule, 20, flat, flat)
    assert developments[:, 0].tolist() == list(range(20))


@st.composite
def histories(draw, num_phases: int) -> tuple[list[dict[str, float]], list[dict[str, float]]]:
    values = st.floats(0, 1, width=32)
    fitness = st.one_of(st.floats(-1e6, 1e6, width=32), st.just(-math.inf))
    rows = st.builds(metrics, values, fitness, st.floats(-1e6, 1e6, width=32))
    return draw(st.lists(rows, min_size=num_phases, max_size=num_phases)), draw(
        st.lists(rows, min_size=num_phases, max_size=num_phases)
    )


@pytest.mark.parametrize("text, num_phases", [(SMOL_PACED, 20), (TWO_CLOCKS, 12)])
@settings(max_examples=25, deadline=None)
@given(data=st.data())
def test_every_realised_trajectory_keeps_the_certificate(text, num_phases, data):
    """For any metric history: bounds, monotone where declared, development never ahead of
    the budget nor slower than a step per bound, waits never longer than the bound, and the
    final body from the tail phase on."""
    schedule = smol_dsl.parse(text)
    history, after = data.draw(histories(num_phases))
    developments, bodies, waits = realised(schedule, num_phases, history, after)
    tail_phase = schedule.tail_phase(num_phases)
    for column, channel in enumerate(schedule.channels):
        curve = schedule.curve(channel)
        certificate = curve.certificate
        realised_values = bodies[:, column]
        assert np.all(realised_values >= np.float32(certificate.minimum) - 1e-6)
        assert np.all(realised_values <= np.float32(certificate.maximum) + 1e-6)
        assert np.all(realised_values[tail_phase:] == np.float32(certificate.final))
        steps = np.diff(realised_values)
        monotone = {piece.monotone for piece in certificate.pieces if piece.kind != "tail"}
        if monotone == {"decreasing"}:
            assert np.all(steps <= 0)
        if monotone == {"increasing"}:
            assert np.all(steps >= 0)
    phases = np.arange(num_phases)
    for index, clock in enumerate(schedule.pacing.clocks):
        development = developments[:, index]
        assert np.all(development <= phases) and np.all(development >= phases // clock.within)
        assert np.all(np.diff(development[:tail_phase]) <= 1)
        assert np.all(waits[:, index] < clock.within)


def test_the_decision_is_jittable_and_vmaps_over_runs():
    schedule = smol_dsl.parse(SMOL_PACED)
    pacing = schedule.pacing
    states = jax.vmap(pacing.initial)({name: jnp.asarray([0.5, 0.5]) for name in METRICS})
    coverage = jnp.asarray([0.4, 0.46])
    decided = jax.jit(jax.vmap(lambda s, m: pacing.decide(s, m, 0, 18)))(
        states, {"coverage": coverage, "max_fitness": jnp.zeros(2), "qd_score": jnp.zeros(2)}
    )
    assert isinstance(decided, PaceState) and decided.development.tolist() == [[0], [1]]


def test_plot_draws_a_paced_schedule_with_its_envelope(tmp_path, capsys):
    path = tmp_path / "paced.sched"
    path.write_text(SMOL_PACED)
    out = tmp_path / "paced.png"
    assert main(["plot", str(path), "smol", "--phases", "20", "-o", str(out)]) == 0
    assert out.stat().st_size > 10_000 and "SMOL-paced, SMOL; 20 phases" in capsys.readouterr().out


def test_the_qdax_pacing_functions_refuse_metrics_they_cannot_read():
    from smol_dsl import qdax as smol

    schedule = smol_dsl.parse(SMOL_PACED)
    with pytest.raises(ValueError, match="missing qd_score"):
        smol.pacing_start(schedule, {"coverage": 50.0, "max_fitness": 1.0})
    state = smol.pacing_start(schedule, metrics(50.0))
    unpaced = smol_dsl.load("smol")  # no clocks: the body moves on at every boundary
    plain = smol.pacing_start(unpaced, metrics(50.0))
    assert plain.development.shape == (0,)
    assert bool(smol.body_moves(unpaced, plain, smol.pace(unpaced, plain, metrics(10.0), 0, 20), 1, 20))
    assert not bool(smol.body_moves(schedule, state, smol.pace(schedule, state, metrics(10.0), 0, 20), 1, 20))


def test_a_channel_a_paced_file_does_not_declare_never_moves_its_body():
    """In a sweep beside a schedule of more channels, a paced gear-only run's other channels
    (1 throughout) keep one index, so a boundary where its clock stands still is a hold."""
    schedule = smol_dsl.parse(SMOL_PACED)
    held = [np.asarray(schedule.phase_indices([2], phase, 20, ("gear", "mass"))).tolist() for phase in (3, 4)]
    assert held == [[2, 0], [2, 0]]
    assert np.asarray(schedule.phase_indices([2], 18, 20, ("gear", "mass"))).tolist() == [18, 0]
    unpaced = smol_dsl.load("smol")  # without pace: every channel at the budget's phase
    assert np.asarray(unpaced.phase_indices([], 4, 20, ("gear", "mass"))).tolist() == [4, 4]
