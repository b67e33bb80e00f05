"""Multi-channel schedules: `channel` sections, `final` bodies, per-channel proofs and
certificates, `Schedule.curve`, `phase_values`, `check_targets`, and the CLI's `check --task` and
`plot` of several channels."""

from __future__ import annotations

import io
import re
import zlib
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import smol_dsl
from smol_dsl import GEAR, Anatomy, Channel, ScheduleError
from smol_dsl.cli import main
from smol_dsl.language.curve import Curve

MASS = Channel("mass")
LEFT_LEG = Channel("gear", ("left_leg",))
GRAVITY = Channel("gravity")
FRICTION = Channel("friction")

TAIL = "90% .. 100%: tail\n"

THREE = """name "Three"
let m0 = 0.3
extinction 0.05

channel mass
  bounds 0.3 .. 1
  0% .. 90%: linear m0 -> 1 increasing
  90% .. 100%: tail

channel gear
  0% .. 90%: expr (m0 + (1 - m0) * t / 0.9) ** (2/3)
  90% .. 100%: tail

channel gear[left_leg]
  final 0.5
  0% .. 30%: constant 1
  30% .. 90%: linear 1 -> 0.5 decreasing
  90% .. 100%: tail
"""

BODY = Anatomy(
    actuators=("hip", "knee", "hip_left", "knee_left"),
    links=("torso", "thigh", "thigh_left"),
    actuator_groups={"left_leg": ("hip_left", "knee_left")},
    link_groups={"left_leg": ("thigh_left",)},
)


@pytest.fixture(scope="module")
def three() -> smol_dsl.Schedule:
    return smol_dsl.parse(THREE, path="three.sched")


# ----------------------------------------------------------------------------- parsing


def test_channels_are_in_declared_order_with_canonical_names(three):
    assert three.channels == (MASS, GEAR, LEFT_LEG)
    assert [c.name for c in three.channels] == ["mass", "gear", "gear[left_leg]"]
    assert three.extinction == 0.05 and three.name == "Three"


def test_a_file_without_channel_lines_schedules_plain_gear(library):
    for name in ("smol", "human", "random", "vanilla"):
        assert library[name].channels == (GEAR,)
        assert library[name].certificates == {GEAR: library[name].certificate}


def test_lines_before_the_first_channel_line_are_the_gear_channels():
    schedule = smol_dsl.parse("bounds 1 .. 2\n0% .. 90%: constant 1.5\n" + TAIL + "channel mass\n0% .. 100%: tail\n")
    assert schedule.channels == (GEAR, MASS)
    assert schedule.certificate.bounds == (1.0, 2.0) and schedule.curve(MASS).certificate.bounds is None


def test_indentation_is_optional_and_lets_are_global():
    indented = "channel mass\n    let a = 0.5\n  0% .. 90%: constant b\n" + TAIL + "channel gravity\n let b = 0.75\n"
    flat = indented.replace("    ", "").replace("  ", "").replace(" let", "let") + "0% .. 90%: constant a\n" + TAIL
    schedule = smol_dsl.parse(indented + "0% .. 90%: constant a\n" + TAIL)
    assert np.array_equal(schedule.phase_values(10), smol_dsl.parse(flat).phase_values(10))
    assert schedule.phase_values(10)[0].tolist() == [0.75, 0.5]


def test_targets_in_any_order_are_one_channel_with_one_name():
    schedule = smol_dsl.parse("channel mass[torso, thigh]\n0% .. 100%: tail\n")
    assert schedule.channels == (Channel("mass", ("thigh", "torso")),) == (Channel("mass", ("torso", "thigh")),)
    assert schedule.channels[0].name == "mass[thigh,torso]" == Channel.parse("mass[torso, thigh]").name


RANDOM_MASS = "channel mass[{}]\n0% .. 90%: random 0.5 .. 1.5 every 10%\n90% .. 100%: tail\n"


def test_a_channel_is_the_same_in_the_api_however_its_targets_are_ordered():
    written, reordered = (smol_dsl.parse(RANDOM_MASS.format(t)) for t in ("torso, thigh", "thigh,torso"))
    key = jax.random.key(7)
    # the random draws come from the canonical name, not the order written
    assert np.array_equal(written.phase_values(20, key), reordered.phase_values(20, key))
    for spelling in ("mass[thigh,torso]", "mass[torso, thigh]", Channel("mass", ("torso", "thigh"))):
        assert written.curve(spelling) is written.curve(written.channels[0])
        column = written.phase_values(20, key, channels=(spelling,))[:, 0]
        assert np.array_equal(column, written.phase_values(20, key)[:, 0])
        assert not np.all(np.asarray(column) == 1)


def test_a_channel_the_file_lacks_is_an_error_unless_the_api_says_it_is_one(three, library):
    with pytest.raises(ValueError, match=r"declares no channel mass\[torso\]; it declares mass, gear"):
        three.curve("mass[torso]")
    assert float(three.curve("friction", or_standard=True).value(0.3)) == 1.0
    # documented: phase_values of chosen channels gives 1 for one the file lacks, and alpha is
    # 1 throughout in a file that does not schedule plain gear
    assert np.all(np.asarray(three.phase_values(5, channels=("friction",))) == 1)
    assert np.all(np.asarray(library["low-gravity"].phase_alphas(5)) == 1)


@pytest.mark.parametrize(
    "name, error, message",
    [
        ("mass[torso,torso]", ValueError, "names 'torso' twice"),
        ("mass[torso,,thigh]", ValueError, "empty"),
        ("friction[torso]", ValueError, "takes no targets"),
        ("strength", ValueError, "not a channel"),
        (None, TypeError, "not None"),
        (3, TypeError, "not 3"),
    ],
)
def test_channel_names_that_are_no_channel_are_refused(name, error, message):
    with pytest.raises(error, match=re.escape(message)):
        Channel.parse(name)


def test_curve_takes_a_channel_or_its_name(three):
    assert three.curve("gear[left_leg]") is three.curve(LEFT_LEG)
    assert three.curve("mass").channel == MASS
    with pytest.raises(ValueError, match="not a channel"):
        three.curve("strength")


# ----------------------------------------------------------------------------- errors

# (text, line, column, caret length, words in the message, words in the hint)
ERRORS = {
    "unknown kind": (
        "channel strenght\n0% .. 100%: tail\n",
        1, 9, 8, "unknown channel `strenght`", "the channels are `gear`: the actuators' gear",
    ),
    "did you mean": ("channel gravty\n0% .. 100%: tail\n", 1, 9, 6, "unknown channel", "did you mean `gravity`?"),
    "friction with targets": (
        "channel friction[torso]\n0% .. 100%: tail\n",
        1, 17, 7, "`friction` takes no targets", "write `channel friction`",
    ),
    "gravity with targets": ("channel gravity[a]\n0% .. 100%: tail\n", 1, 16, 3, "takes no targets", "gravity"),
    "empty targets": ("channel gear[]\n0% .. 100%: tail\n", 1, 13, 2, "`gear[]` names no actuators", "left_leg"),
    "empty mass targets": ("channel mass[ ]\n0% .. 100%: tail\n", 1, 13, 3, "names no links", "channel mass"),
    "repeated target": (
        "channel gear[left_leg, hip, left_leg]\n0% .. 100%: tail\n",
        1, 29, 8, "`left_leg` is named twice", "once",
    ),
    "channel twice": (
        "channel mass\n0% .. 100%: tail\nchannel gravity\n0% .. 100%: tail\nchannel mass\n0% .. 100%: tail\n",
        5, 1, 12, "`channel mass` is given twice (first on line 1)", "merge",
    ),
    "targets reordered twice": (
        "channel gear[a, b]\n0% .. 100%: tail\nchannel gear[b,a]\n0% .. 100%: tail\n",
        3, 1, 17, "`channel gear[a, b]` is given twice (first on line 1, and here as `gear[b, a]`)", "any order",
    ),
    "gear after implicit gear": (
        "\n0% .. 100%: tail\nchannel gear\n0% .. 100%: tail\n",
        3, 1, 12, "`channel gear` is given twice: the lines before the first `channel` line (from line 2)",
        "move those lines",
    ),
    "bounds without segments before a channel": (
        "continuous\nbounds 0.5 .. 1\nchannel mass\n0% .. 100%: tail\n",
        1, 1, 10, "`continuous` comes before the first `channel` line", "move it below",
    ),
    "channel without segments": (
        "channel mass\n0% .. 100%: tail\nchannel gravity\nchannel friction\n0% .. 100%: tail\n",
        3, 1, 15, "channel gravity has no segments", "add segments",
    ),
    "final twice": (
        "channel mass\nfinal 0.5\nfinal 0.5\n0% .. 100%: tail\n",
        3, 1, 9, "`final` is given twice (first on line 2)", "channel mass has at most one `final` line",
    ),
    "bounds twice in a channel": (
        "channel mass\nbounds 0 .. 2\n0% .. 100%: tail\nbounds 0 .. 2\n",
        4, 1, 13, "`bounds` is given twice (first on line 2)", "channel mass has at most one",
    ),
    "final not positive": (
        "channel mass\n  final 1 - 1\n0% .. 100%: tail\n",
        2, 3, 11, "the final value of mass must be above 0, not 0", "final 0.5",
    ),
    "final unknown name": ("channel mass\nfinal half\n0% .. 100%: tail\n", 2, 7, 4, "unknown name `half`", "let"),
    "mass not positive": (
        "channel mass\n0% .. 90%: linear 1 -> -0.5\n" + TAIL,
        2, 1, 27, "mass must stay above 0, but segment 1 of mass (0% .. 90%, linear) goes down to -0.5",
        "mass scales the links' mass and rotational inertia, together; 0 or less would make the links weightless",
    ),
    "gravity zero": (
        "channel gravity\n0% .. 90%: constant 0\n" + TAIL,
        2, 1, 21, "gravity must stay above 0", "would switch gravity off",
    ),
    "gear of several files is named": (
        "0% .. 90%: linear 1 -> 0\n" + TAIL + "channel mass\n0% .. 100%: tail\n",
        1, 1, 24, "alpha must stay above 0, but segment 1 of gear (0% .. 90%, linear) goes down to 0",
        "gear scales the actuators' gear (their strength); 0 or less would switch them off",
    ),
    "final tail too short": (
        "channel gear[left_leg]\nfinal 0.5\n0% .. 95%: linear 1 -> 0.5\n95% .. 100%: tail\n",
        4, 1, 17,
        "gear[left_leg] must end at its declared final value, gear[left_leg] = 0.5, over at least the final 10% "
        "of the run; it has gear[left_leg] == 0.5 only from 95%",
        "`tail` is 0.5 here",
    ),
    "final tail missing": (
        "channel mass\nfinal 0.5\n0% .. 100%: constant 1\n",
        3, 1, 22, "it has no mass = 0.5 tail", "90% .. 100%: tail",
    ),
    "tail at 1 is not a final 0.5": (
        "channel mass\nfinal 0.5\n0% .. 90%: constant 0.5\n90% .. 100%: constant 1\n",
        4, 1, 23, "no mass = 0.5 tail", "finish the section",
    ),
    "gap in a channel": (
        "channel mass\n0% .. 40%: constant 1\n50% .. 100%: tail\n",
        3, 1, 17, "gap between 40% and 50% in mass", "segment 1 (line 2) ends at 40%",
    ),
    "uncovered start": ("channel mass\n10% .. 100%: tail\n", 2, 1, 17, "the segments of mass leave 0% .. 10%", "0%"),
    "mass bounds": (
        "channel mass\nbounds 0.5 .. 1\n0% .. 90%: linear 0.3 -> 1\n" + TAIL,
        3, 1, 26, "segment 1 of mass (0% .. 90%, linear) goes down to mass = 0.3, 0.2 below the declared bound 0.5",
        "widen `bounds 0.5 .. 1`",
    ),
    "mass monotone": (
        "channel mass\n0% .. 90%: linear 0.3 -> 1 decreasing\n" + TAIL,
        2, 1, 37, "is declared decreasing but is not: mass goes from 0.3 at 0% to 1 at 90%", "remove `decreasing`",
    ),
    "mass continuous": (
        "channel mass\ncontinuous\n0% .. 90%: constant 0.5\n" + TAIL,
        4, 1, 17, "mass is declared continuous but has a jump of +0.5 at 90%", "drop `continuous`",
    ),
    "segment position named": (
        "channel mass\n0% .. 140%: tail\n", 2, 7, 4, "the end of segment 1 of mass is 140%, outside the run", "90%",
    ),
    "square brackets in an expression": (
        "channel mass\n0% .. 90%: constant [0.5]\n" + TAIL,
        2, 21, 1, "unexpected character '['", "group with round brackets",
    ),
    "closing bracket in an expression": (
        "0% .. 90%: linear 1 -> 2]\n" + TAIL, 1, 25, 1, "unexpected character ']'", "group with round brackets",
    ),
    "no kind": ("channel\n0% .. 100%: tail\n", 1, 8, 1, "unexpected end of line", "a channel line is `channel KIND`"),
    "unclosed targets": ("channel gear[left_leg\n", 1, 22, 1, "unexpected end of line", "`channel gear[left_leg]`"),
    "trailing comma": ("channel gear[left_leg,]\n", 1, 23, 1, "unexpected ']'", "a channel line is"),
    "final without value": ("channel mass\nfinal\n0% .. 100%: tail\n", 2, 6, 1, "unexpected end of line", "final 0.5"),
    "final is reserved": ("let final = 0.5\n0% .. 100%: tail\n", 1, 1, 15, "`final` is a reserved word", "another"),
    "channel is reserved": ("let channel = 1\n0% .. 100%: tail\n", 1, 1, 15, "`channel` is a reserved word", "another"),
    "mass not finite in float32": (
        "channel mass\n0% .. 90%: expr 1 + (1e20*t)**2/(1e20*t**2+1e40)\n" + TAIL,
        2, 1, 48, "segment 1 of mass (0% .. 90%, expr) cannot be evaluated safely in float32",
        "mass is computed in 32-bit floats (JAX's default)",
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", list(ERRORS))
def test_channel_errors_are_located(case):
    text, line, column, length, message, hint = ERRORS[case]
    with pytest.raises(ScheduleError) as caught:
        smol_dsl.parse(text, path="c.sched")
    error = caught.value
    assert (error.line, error.column, error.span.length) == (line, column, length), str(error)
    assert message in error.message, str(error)
    assert hint in error.hint, str(error)
    rendered = str(error)
    assert rendered.startswith(f"c.sched:{line}:{column}: error: ") and "\nhint: " in rendered


def test_plain_gear_keeps_its_messages_word_for_word():
    text = "0% .. 90%: linear 1 -> -0.5\n" + TAIL
    for variant in (text, "channel gear\n" + text):
        with pytest.raises(ScheduleError) as caught:
            smol_dsl.parse(variant)
        assert caught.value.message == ("alpha must stay above 0, but segment 1 (0% .. 90%, linear) goes down to -0.5")
        assert caught.value.hint == "alpha scales the actuators' gear; 0 or less would switch them off or reverse them"
    with pytest.raises(ScheduleError) as caught:
        smol_dsl.parse("channel gear\n0% .. 95%: linear 1.5 -> 1\n95% .. 100%: tail\n")
    assert caught.value.message.startswith("the schedule must end with alpha = 1 over at least the final 10%")
    with pytest.raises(ScheduleError) as caught:
        smol_dsl.parse("0% .. 90%: expr 1 + (1e20*t)**2/(1e20*t**2+1e40)\n" + TAIL)
    assert caught.value.hint.startswith("alpha is computed in 32-bit floats (JAX's default): keep every part")


# ----------------------------------------------------------------------------- certificates and final bodies


def test_each_channel_has_its_certificate(three):
    certificates = three.certificates
    assert list(certificates) == [MASS, GEAR, LEFT_LEG]
    leg = certificates[LEFT_LEG]
    assert (leg.channel, leg.final, leg.minimum, leg.maximum, leg.tail_start) == (LEFT_LEG, 0.5, 0.5, 1.0, 0.9)
    text = str(leg)
    assert "gear[left_leg] in [0.5, 1]   gear[left_leg] > 0: proven" in text
    assert "tail: gear[left_leg] == 0.5 from 90% to 100% (10% of the run, at least 10% required): proven" in text
    assert "alpha" not in text
    assert "tail: mass == 1 from 90%" in str(certificates[MASS])
    assert "alpha in [0.44814, 1]" in str(certificates[GEAR])
    assert leg.to_dict()["channel"] == "gear[left_leg]" and leg.to_dict()["final"] == 0.5
    assert all(c.extinction == 0.05 for c in certificates.values())


def test_final_body_and_final_differences(three, library):
    assert three.final_body == {MASS: 1.0, GEAR: 1.0, LEFT_LEG: 0.5}
    assert library["smol"].final_body == {GEAR: 1.0}
    assert three.final_differences(library["smol"]) == ["gear[left_leg]"]
    assert library["smol"].final_differences(three) == ["gear[left_leg]"]
    assert library["smol"].final_differences(library["human"]) == []
    assert library["growth"].final_differences(library["vanilla"]) == []  # undeclared channels end at 1
    other = smol_dsl.parse("channel mass\nfinal 2\n0% .. 100%: tail\n")
    assert three.final_differences(other) == ["mass", "gear[left_leg]"]


def test_the_final_value_is_the_tail_in_jax(three):
    leg = three.curve(LEFT_LEG)
    assert leg.final == 0.5 and leg.tail_start == pytest.approx(0.9)
    values = np.asarray(leg.phase_values(100))
    assert np.all(values[90:] == np.float32(0.5)) and values[0] == 1.0
    assert float(leg.value(0.95)) == 0.5 == float(leg.value(1.0))


def test_a_final_value_that_is_not_a_float32_is_rounded_once():
    schedule = smol_dsl.parse("channel mass\nfinal 0.3\n0% .. 100%: tail\n")
    certificate = schedule.certificates[MASS]
    assert 0 < certificate.float32_error <= 2**-24 * 0.3 * 1.01
    assert np.all(np.asarray(schedule.phase_values(8)) == np.float32(0.3))


def test_a_tail_may_be_any_segment_equal_to_the_final_value():
    schedule = smol_dsl.parse(
        "channel mass\nfinal 1/2\n0% .. 50%: linear 1 -> 0.5\n50% .. 80%: expr u - u + 0.5\n80% .. 100%: tail\n"
    )
    assert schedule.curve(MASS).tail_start == pytest.approx(0.5)
    assert schedule.tail_start == pytest.approx(0.5)


def test_tail_start_is_the_latest_channels_and_tail_phases_use_it():
    schedule = smol_dsl.parse(
        "0% .. 50%: constant 1.5\n50% .. 100%: tail\nchannel mass\n0% .. 80%: constant 0.5\n80% .. 100%: tail\n"
    )
    assert schedule.curve(GEAR).tail_start == pytest.approx(0.5)
    assert schedule.tail_start == pytest.approx(0.8)
    assert schedule.tail_phases(100) == 20 and schedule.tail_phases(7) == 1


def test_a_file_without_plain_gear_has_alpha_one_throughout(library):
    leg = library["leg-damage"]
    assert leg.channels == (LEFT_LEG,)
    assert np.all(np.asarray(leg.phase_alphas(50)) == 1.0) and float(leg.alpha(0.3)) == 1.0
    assert leg.certificate.tail_start == 0 and leg.certificate.channel == GEAR
    assert GEAR not in leg.certificates
    assert leg.segments == leg.curve(GEAR, or_standard=True).segments and len(leg.segments) == 1


def test_repr_mentions_the_channels(three, library):
    assert "channels=mass, gear, gear[left_leg]" in repr(three)
    assert "channels=gear," in repr(library["smol"])
    assert "Curve(gear[left_leg]" in repr(three.curve(LEFT_LEG))


# ----------------------------------------------------------------------------- check_targets


def test_check_targets_accepts_names_and_groups():
    for text in ("channel gear[left_leg, hip]", "channel mass[left_leg, torso]", "channel gravity", "channel gear"):
        smol_dsl.parse(text + "\n0% .. 100%: tail\n").check_targets(BODY.targets(), "toy", BODY.listing())


def test_check_targets_locates_a_target_the_body_lacks():
    schedule = smol_dsl.parse(
        "channel mass\n0% .. 100%: tail\nchannel gear[hip, left_lge]\n0% .. 100%: tail\n", path="b.sched"
    )
    with pytest.raises(ScheduleError) as caught:
        schedule.check_targets(BODY.targets(), "toy", BODY.listing())
    error = caught.value
    assert (error.path, error.line, error.column, error.span.length) == ("b.sched", 3, 19, 8)
    assert error.message == "task toy has no actuators named `left_lge`"
    assert error.hint.startswith(
        "did you mean `left_leg`? toy's actuators: hip, knee, hip_left, knee_left; groups: left_leg"
    )
    assert "^^^^^^^^" in str(error)


def test_check_targets_knows_links_from_actuators():
    schedule = smol_dsl.parse("channel mass[knee]\n0% .. 100%: tail\n")
    with pytest.raises(ScheduleError, match="task toy has no links named `knee`") as caught:
        schedule.check_targets(BODY.targets(), "toy", BODY.listing())
    assert "links: torso, thigh, thigh_left" in caught.value.hint


def test_check_targets_for_a_task_that_lists_no_targets():
    smol_dsl.parse("channel mass\n0% .. 100%: tail\n").check_targets(None, "blob")  # no targets: nothing to check
    schedule = smol_dsl.parse("channel gear[a, b]\n0% .. 100%: tail\n")
    with pytest.raises(ScheduleError, match="task blob does not list its actuators") as caught:
        schedule.check_targets(None, "blob")
    assert (caught.value.line, caught.value.column, caught.value.span.length) == (1, 14, 4)


def test_walker2d_has_the_leg_damage_group(library):
    from smol_dsl.tasks import task_spec

    spec = task_spec("walker2d")
    spec.check_schedule(library["leg-damage"])
    spec.check_schedule(library["growth"])
    assert spec.anatomy.indices(LEFT_LEG) == (3, 4, 5)


# ----------------------------------------------------------------------------- phase values


def test_phase_values_has_a_column_per_channel(three):
    key = jax.random.key(7)
    values = three.phase_values(100, key)
    assert values.shape == (100, 3) and values.dtype == jnp.float32
    for column, channel in enumerate(three.channels):
        assert np.array_equal(np.asarray(values[:, column]), np.asarray(three.curve(channel).phase_values(100, key)))


def test_phase_values_of_chosen_channels_has_ones_for_undeclared_ones(three):
    chosen = (GRAVITY, LEFT_LEG, GEAR, FRICTION)
    values = np.asarray(three.phase_values(20, None, chosen))
    assert values.shape == (20, 4)
    assert np.all(values[:, 0] == 1.0) and np.all(values[:, 3] == 1.0)
    assert np.array_equal(values[:, 1], np.asarray(three.curve(LEFT_LEG).phase_values(20)))
    assert np.array_equal(values[:, 2], np.asarray(three.phase_alphas(20)))
    assert np.array_equal(three.checked_phase_values(20, None, chosen), values)
    by_name = three.phase_values(20, None, ["gravity", "gear[left_leg]", "gear", "friction"])
    assert np.array_equal(np.asarray(by_name), values)
    with pytest.raises(ValueError, match="not a channel"):
        three.phase_values(20, None, ["strength"])


def test_one_channel_files_give_their_alphas_bit_for_bit(library):
    for name, schedule in library.items():
        if schedule.channels != (GEAR,):
            continue
        for num_phases in (7, 100, 137):
            key = jax.random.key(num_phases)
            values = schedule.checked_phase_values(num_phases, key)
            alphas = schedule.checked_phase_alphas(num_phases, key)
            assert values.shape == (num_phases, 1) and values.dtype == alphas.dtype == np.float32, name
            assert values[:, 0].tobytes() == alphas.tobytes(), name


def test_an_explicit_channel_gear_is_the_file_without_it(library):
    for name in ("smol", "human", "random"):
        plain = library[name]
        explicit = smol_dsl.parse("channel gear\n" + plain.source)
        assert str(explicit.certificate) == str(plain.certificate)
        key = jax.random.key(3)
        assert (
            np.asarray(explicit.phase_values(100, key)).tobytes() == np.asarray(plain.phase_values(100, key)).tobytes()
        )


def test_phase_value_with_a_traced_phase_is_phase_values(three):
    key = jax.random.key(1)
    compiled = jax.jit(lambda k, key: three.phase_value(k, 50, key))
    rows = np.stack([np.asarray(compiled(jnp.int32(k), key)) for k in (0, 13, 49)])
    assert rows.shape == (3, 3)
    np.testing.assert_array_equal(rows, np.asarray(three.phase_values(50, key))[[0, 13, 49]])
    assert three.phase_value(jnp.arange(50), 50, key, (GEAR, GRAVITY)).shape == (50, 2)


def test_phase_values_under_jit_with_a_traced_key(three):
    jitted = jax.jit(lambda key: three.phase_values(40, key))
    key = jax.random.key(11)
    np.testing.assert_array_equal(np.asarray(jitted(key)), np.asarray(three.phase_values(40, key)))


def test_checked_phase_values_refuses_a_bad_value_with_a_located_error(monkeypatch, three):
    leg = three.curve(LEFT_LEG)
    table = np.array(leg.phase_values(10))
    table[4] = 0.0
    monkeypatch.setattr(leg, "phase_values", lambda n, key=None: table)
    with pytest.raises(ScheduleError, match=r"gear\[left_leg\] of phase 4 of 10 \(t = 40%, segment 2\)") as caught:
        three.checked_phase_values(10)
    assert caught.value.path == "three.sched" and caught.value.line == 17


# ----------------------------------------------------------------------------- random draws per channel

RANDOM = "0% .. 50%: random 0.5 .. 1.5 every 5%\n50% .. 100%: tail\n"


def test_plain_gear_draws_as_a_file_of_one_channel():
    key = jax.random.key(5)
    alone = smol_dsl.parse(RANDOM)
    mixed = smol_dsl.parse(RANDOM + "channel mass\n" + RANDOM)
    assert np.array_equal(np.asarray(mixed.phase_alphas(100, key)), np.asarray(alone.phase_alphas(100, key)))


def test_other_channels_draw_from_a_key_folded_with_their_name():
    key = jax.random.key(5)
    alone = smol_dsl.parse(RANDOM)
    mixed = smol_dsl.parse("channel mass[thigh]\n" + RANDOM + "channel gear\n" + RANDOM)
    folded = jax.random.fold_in(key, zlib.crc32(b"mass[thigh]"))
    mass = np.asarray(mixed.curve("mass[thigh]").phase_values(100, key))
    assert np.array_equal(mass, np.asarray(alone.phase_alphas(100, folded)))
    assert not np.array_equal(mass, np.asarray(mixed.phase_alphas(100, key)))  # channels draw independently


def test_declaration_order_does_not_change_values():
    sections = {
        "mass": "channel mass\n" + RANDOM,
        "gear": "channel gear\n0% .. 90%: linear 1.5 -> 1\n" + TAIL,
        "gravity": "channel gravity\n" + RANDOM.replace("0.5 .. 1.5", "0.2 .. 1"),
    }
    forward = smol_dsl.parse("".join(sections.values()))
    backward = smol_dsl.parse("".join(reversed(sections.values())))
    key = jax.random.key(9)
    chosen = (MASS, GEAR, GRAVITY)
    assert np.array_equal(
        np.asarray(forward.phase_values(64, key, chosen)), np.asarray(backward.phase_values(64, key, chosen))
    )


def test_curve_is_the_public_per_channel_object(three):
    curve = three.curve(MASS)
    assert isinstance(curve, Curve) and curve.name == "mass"
    assert float(curve.as_optax(100, num_phases=10)(95)) == 1.0
    assert curve.draws() == [None, None]
    assert curve.symbolic.free_symbols and curve.segments[0].owner == " of mass"


# ----------------------------------------------------------------------------- the bundled channel curricula


def test_growth_strength_is_mass_to_the_two_thirds(library):
    growth = library["growth"]
    assert growth.channels == (MASS, GEAR)
    values = np.asarray(growth.phase_values(100), dtype=np.float64)
    np.testing.assert_allclose(values[:, 1], values[:, 0] ** (2 / 3), rtol=2e-6)
    assert values[0, 0] == pytest.approx(0.3) and np.all(values[90:] == 1.0)


def test_low_gravity_starts_on_the_moon(library):
    gravity = library["low-gravity"].curve(GRAVITY)
    values = np.asarray(gravity.phase_values(100))
    assert values[0] == np.float32(0.165) and np.all(values[:31] == np.float32(0.165))
    assert np.all(np.diff(values[30:91]) > 0) and np.all(values[90:] == 1.0)


def test_leg_damage_ends_on_a_damaged_body(library):
    leg = library["leg-damage"]
    assert leg.final_body == {LEFT_LEG: 0.5}
    assert "left_leg" in leg.description and "walker2d" in leg.description


# ----------------------------------------------------------------------------- CLI


def test_check_prints_a_certificate_per_channel(capsys):
    assert main(["check", "growth"]) == 0
    out = capsys.readouterr().out
    assert "channel mass:\n  mass in [0.3, 1]" in out and "channel gear:\n  alpha in [0.44814, 1]" in out
    assert main(["check", "leg-damage"]) == 0
    out = capsys.readouterr().out
    assert "channel " not in out.split("\n", 1)[1] and "tail: gear[left_leg] == 0.5 from 90%" in out


def test_check_task_lists_the_body(capsys):
    assert main(["check", "leg-damage", "growth", "--task", "walker2d"]) == 0
    out = capsys.readouterr().out
    assert "walker2d: actuators: thigh_joint, leg_joint" in out and "groups: right_leg" in out
    assert "walker2d: links: torso, thigh" in out and out.count(": ok: ") == 2


def test_check_task_refuses_a_body_mismatch(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    Path("hurt.sched").write_text("channel gear[left_lge]\n0% .. 100%: tail\n")
    assert main(["check", "hurt.sched", "--task", "walker2d", "-q"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("hurt.sched:1:14: error: task walker2d has no actuators named `left_lge`")
    assert "did you mean `left_leg`?" in captured.err and "Traceback" not in captured.err


def test_check_task_refuses_an_unknown_task(capsys):
    assert main(["check", "smol", "--task", "walker3d"]) == 2
    err = capsys.readouterr().err
    assert "unknown task 'walker3d'" in err and err.count("error") == 1


def test_plot_draws_a_panel_per_channel():
    from smol_dsl.results.schedule_figures import schedule_figure

    schedules = [smol_dsl.load(name) for name in ("growth", "low-gravity", "smol")]
    figure = schedule_figure(schedules, num_phases=20)
    labels = [axes.get_ylabel() for axes in figure.axes]
    assert labels == ["mass (factor)", "α (actuator gear scale)", "gravity (factor)"]
    assert all(len(axes.get_lines()) >= 2 * len(schedules) for axes in figure.axes)
    assert len(schedule_figure(schedules[2:], num_phases=20).axes) == 1


def test_plot_cli_writes_a_multi_channel_figure(tmp_path, capsys):
    out = tmp_path / "channels.png"
    assert main(["plot", "growth", "leg-damage", "-o", str(out), "--phases", "20"]) == 0
    assert out.stat().st_size > 0 and "Growth, Leg damage" in capsys.readouterr().out


def test_plot_seed_draws_what_run_seed_draws(tmp_path, monkeypatch, capsys, library):
    """`plot random --seed 3` shows the alphas `run ... random --seed 3` trains under."""
    from smol_dsl.results import figures
    from smol_dsl.runner import preset_config
    from smol_dsl.seeds import schedule_key

    drawn = {}
    monkeypatch.setattr(figures, "save_figure", lambda figure, out: drawn.setdefault("figure", figure))
    assert main(["plot", "random", "--seed", "3", "--phases", "10", "-o", str(tmp_path / "r.png")]) == 0
    steps = drawn["figure"].axes[0].get_lines()[0].get_ydata()[:-1]  # the step line, its last value repeated
    config = preset_config("walker2d", seed=3, num_phases=10)
    trained = library["random"].checked_phase_values(config.num_phases, schedule_key(config.seed), (GEAR,))[:, 0]
    np.testing.assert_array_equal(steps, trained)
    assert not np.array_equal(trained, np.asarray(library["random"].phase_alphas(10, jax.random.key(3))))


def test_a_file_of_many_channels_plots_a_panel_per_kind_without_warnings(recwarn):
    from smol_dsl.results.schedule_figures import schedule_figure

    links = ("torso", "thigh", "leg", "foot", "thigh_left", "leg_left", "foot_left", "right_leg", "left_leg")
    links += ("torso, thigh", "leg, foot")  # 11 mass channels: more than a legend inside a panel holds
    sections = [f"channel mass[{link}]\n0% .. 90%: linear 1 -> 0.{k + 2:02d}\n{TAIL}" for k, link in enumerate(links)]
    sections += [
        f"channel gear[{g}]\n0% .. 90%: constant 1.{k + 1}\n{TAIL}" for k, g in enumerate(("left_leg", "right_leg"))
    ]
    many = smol_dsl.parse("".join(sections), path="many.sched")
    figure = schedule_figure([many], num_phases=20)
    assert [axes.get_ylabel() for axes in figure.axes] == ["mass (factor)", "gear (factor)"]
    assert [len(axes.get_lines()) for axes in figure.axes] == [12, 3]  # the channels, and the line at 1
    assert figure.axes[0].get_title() == "11 mass channels" and figure.axes[0].get_legend() is None
    assert figure.axes[1].get_legend() is not None
    assert figure.get_size_inches()[1] < 8
    figure.savefig(io.BytesIO(), format="png")
    assert not [w for w in recwarn if "legend" in str(w.message).lower()]
