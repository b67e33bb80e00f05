"""tasks.ranges: every actuator's and link's factor (the product of the channels that reach
it) is proven within the range the task's physics takes, or the schedule is refused,
located; and what is accepted holds for the factors the physics multiplies `sys` by."""

from __future__ import annotations

import random

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from budget import examples
from hypothesis import given, settings
from hypothesis import strategies as st

import smol_dsl
from smol_dsl import ScheduleError
from smol_dsl.tasks import TASK_NAMES, task_spec
from smol_dsl.tasks.body import kind_factor
from smol_dsl.tasks.physics import PHYSICS_NAMES
from smol_dsl.tasks.ranges import FLOAT32_RANGE, FactorRange, factor_range

TAIL = "90% .. 100%: tail\n"


def refusal(task: str, text: str, physics: str = "spring") -> ScheduleError:
    with pytest.raises(ScheduleError) as caught:
        task_spec(task).check_schedule(smol_dsl.parse(text, path="body.sched"), physics)
    return caught.value


def test_channels_proven_alone_are_refused_when_their_product_leaves_the_range():
    text = f"channel mass\n0% .. 90%: constant 1e-30\n{TAIL}channel mass[torso]\n0% .. 90%: constant 1e-30\n{TAIL}"
    error = refusal("walker2d", text)
    assert "torso's mass factor may go down to 1e-60" in error.message
    assert "the product of `mass` (1e-30 .. 1), `mass[torso]` (1e-30 .. 1)" in error.message
    assert (error.line, error.column) == (2, 1) and "factors of one kind multiply" in error.hint
    assert str(error).startswith("body.sched:2:1: error:")


@pytest.mark.parametrize("physics", PHYSICS_NAMES)
@pytest.mark.parametrize("task", TASK_NAMES)
def test_a_plain_factor_the_physics_cannot_take_is_refused_on_every_task(task, physics):
    ends = 0
    for kind in ("gear", "mass", "friction", "gravity"):
        assert kind in task_spec(task).ranges(physics), f"{task} states no {kind} range on {physics}"
        allowed = factor_range(task_spec(task).ranges(physics), kind)
        for value, way in ((allowed.high * 1.5, "up to"), (allowed.low / 1.5, "down to")):
            if not FLOAT32_RANGE.low < value < FLOAT32_RANGE.high:
                continue  # an end at float32's: the language itself refuses what lies beyond
            ends += 1
            error = refusal(task, f"channel {kind}\n0% .. 90%: constant {value:.6g}\n{TAIL}", physics)
            assert f"the {kind} factor may go {way}" in error.message and (error.line, error.column) == (2, 1)
            assert f"{task} takes {kind} factors from {allowed.low:g} to {allowed.high:g}" in error.hint
    assert ends >= 2  # gear's high and mass's low at least


def test_the_issue_s_plain_gear_of_1e30_is_refused():
    error = refusal("walker2d", f"0% .. 90%: constant 1e30\n{TAIL}")
    assert "the gear factor may go up to 1e+30" in error.message and error.line == 1


@pytest.mark.parametrize("physics", PHYSICS_NAMES)
def test_every_library_schedule_fits_every_task_whose_body_it_names(library, physics):
    for task in TASK_NAMES:
        anatomy = task_spec(task).anatomy
        for _name, schedule in library.items():
            if not any(anatomy.unknown_targets(channel) for channel in schedule.channels):
                task_spec(task).check_schedule(schedule, physics)  # no refusal


def test_a_range_holds_one_and_is_positive():
    for low, high in ((0.0, 2.0), (1.5, 2.0), (0.5, 0.9), (0.5, float("inf"))):
        with pytest.raises(ValueError, match="holds 1"):
            FactorRange(low, high)


# ---------------------------------------------------------------- what the physics gets

WALKER = task_spec("walker2d")
PHASES = 20
TARGETS = {"gear": ("", "[left_leg]", "[thigh_joint, leg_joint]"), "mass": ("", "[torso]", "[right_leg, torso]")}


def random_body_file(rng: random.Random) -> str:
    """A file of one to four channels of random kinds and targets (walker2d's): a constant
    segment at a factor 10**x, x modest (in [-1, 1]), tiny ([-10, -6]) or huge ([12, 25]),
    then a linear segment between modest factors or another constant, then its tail: some
    within walker2d's ranges, some not, some only as a product (two huge gears)."""
    channels: dict[str, None] = {}
    for _ in range(rng.randint(1, 4)):
        kind = rng.choice(("gear", "mass", "friction", "gravity"))
        channels.setdefault(kind + rng.choice(TARGETS.get(kind, ("",))), None)
    lines = []
    for channel in channels:
        lines.append(f"channel {channel}")
        cut = rng.choice((30, 50))
        extreme = 10 ** rng.choice((rng.uniform(-1, 1), rng.uniform(-10, -6), rng.uniform(12, 25)))
        lines.append(f"0% .. {cut}%: constant {extreme:.4g}")
        if rng.random() < 0.5:
            lines.append(f"{cut}% .. 90%: linear {rng.uniform(0.2, 5):.3g} -> {rng.uniform(0.2, 5):.3g}")
        else:
            lines.append(f"{cut}% .. 90%: constant {10 ** rng.choice((rng.uniform(-1, 1), rng.uniform(12, 25))):.4g}")
        lines.append("90% .. 100%: tail")
    return "\n".join(lines) + "\n"


def assert_physics_gets_factors_in_range(schedule: smol_dsl.Schedule) -> None:
    """Every phase's factors, multiplied per part as the physics multiplies them (float32,
    `tasks.body.kind_factor`), are finite and within walker2d's range for their kind."""
    anatomy, channels = WALKER.anatomy, schedule.channels
    bodies = jnp.asarray(schedule.checked_phase_values(PHASES, jax.random.key(0)), dtype=jnp.float32)
    sizes = {"gear": len(anatomy.actuators), "mass": len(anatomy.links), "friction": 1, "gravity": 1}
    for kind, size in sizes.items():
        factors = jax.vmap(lambda body, kind=kind, size=size: kind_factor(anatomy, channels, body, kind, size))
        if not any(channel.kind == kind for channel in channels):
            continue
        values = np.asarray(factors(bodies))
        allowed = factor_range(WALKER.ranges(), kind)
        assert np.isfinite(values).all(), (kind, values)
        # float32 rounding of a product of factors proven in range: a few ulps past the bound
        assert (values >= allowed.low * (1 - 1e-5)).all() and (values <= allowed.high * (1 + 1e-5)).all(), (
            kind,
            values.min(),
            values.max(),
        )


def accepted(text: str) -> smol_dsl.Schedule | None:
    """The schedule if `check --task walker2d` accepts it (None if it is refused, located)."""
    schedule = smol_dsl.parse(text)  # every channel alone is valid: its values are modest or huge, never wrong
    try:
        WALKER.check_schedule(schedule)
    except ScheduleError as error:
        assert error.line is not None and error.hint and "walker2d takes" in error.hint, str(error)
        return None
    return schedule


@settings(max_examples=examples(60), deadline=None)
@given(st.randoms(use_true_random=False))
@pytest.mark.slow  # evaluates each accepted schedule's phase table in JAX
def test_a_body_that_check_accepts_is_one_the_physics_takes(rng):
    """The property of `check`, extended to the body: a multi-channel file that passes
    `check --task walker2d` gives every actuator, link and the whole body, at every phase,
    finite factors within walker2d's stated ranges (the products the physics computes)."""
    text = random_body_file(rng)
    try:
        schedule = accepted(text)
    except ScheduleError:  # a channel alone beyond float32's safe range: refused by the language
        return
    if schedule is not None:
        assert_physics_gets_factors_in_range(schedule)


@pytest.mark.slow  # verifies 100 files
def test_the_random_bodies_are_both_accepted_and_refused():
    """The property above tests something: of 100 drawn files, many are accepted and many
    refused by the body's ranges (not only by the language)."""
    rng = random.Random(17)
    outcomes = {"accepted": 0, "refused": 0, "language": 0}
    for _ in range(100):
        try:
            outcomes["accepted" if accepted(random_body_file(rng)) is not None else "refused"] += 1
        except ScheduleError:
            outcomes["language"] += 1
    assert outcomes["accepted"] >= 15 and outcomes["refused"] >= 15, outcomes
