"""The public Python API: load/parse, alpha, phase_alpha(s), optax-style use, certificates."""

from __future__ import annotations

import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import smol_dsl

SMOL_TEXT = """
name "mine"
0% .. 90%: linear 2 -> 1
90% .. 100%: tail
"""


def test_load_by_bundled_name_with_or_without_suffix(library, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    assert smol_dsl.load("human").source == library["human"].source
    assert smol_dsl.load("human.sched").source == library["human"].source


def test_a_local_file_wins_over_the_bundled_schedule(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    Path("human.sched").write_text(SMOL_TEXT)
    schedule = smol_dsl.load("human.sched")
    assert schedule.name == "mine"
    assert schedule.path == "human.sched"
    assert smol_dsl.load(tmp_path / "human.sched").name == "mine"


def test_missing_schedule_lists_the_library(tmp_path):
    with pytest.raises(smol_dsl.ScheduleError) as caught:
        smol_dsl.load(tmp_path / "nope.sched")
    assert "no such file" in str(caught.value)
    with pytest.raises(smol_dsl.ScheduleError, match="no such file") as caught:
        smol_dsl.load("humane")
    assert "human" in caught.value.hint


def test_parse_keeps_source_and_defaults():
    schedule = smol_dsl.parse(SMOL_TEXT)
    assert schedule.source == SMOL_TEXT
    assert schedule.name == "mine"
    assert schedule.extinction == 0.0
    assert schedule.description == ""
    unnamed = smol_dsl.parse("0% .. 100%: tail")
    assert unnamed.name == "schedule"


def test_alpha_scalar_and_array_shapes(library):
    smol = library["smol"]
    assert smol.alpha(0.0).shape == ()
    assert float(smol.alpha(0.0)) == 1.5
    assert float(smol.alpha(0.45)) == pytest.approx(1.25)
    assert float(smol.alpha(0.9)) == 1.0
    grid = jnp.linspace(0, 1, 11).reshape(11, 1)
    assert smol.alpha(grid).shape == (11, 1)
    # t outside [0, 1] is clipped, as optax schedules clip their counts
    assert float(smol.alpha(-3.0)) == 1.5
    assert float(smol.alpha(7.0)) == 1.0


@pytest.mark.slow  # jits and vmaps every bundled schedule
def test_alpha_is_jittable_and_vmappable(library):
    for schedule in library.values():
        t = jnp.linspace(0, 1, 33)
        key = jax.random.key(3)
        direct = schedule.alpha(t, key)
        jitted = jax.jit(schedule.alpha)(t, key)
        mapped = jax.vmap(schedule.alpha, in_axes=(0, None))(t, key)
        np.testing.assert_allclose(direct, jitted, rtol=1e-6)
        np.testing.assert_allclose(direct, mapped, rtol=1e-6)


def test_alpha_is_differentiable_where_smooth(library):
    slope = jax.grad(lambda t: library["smol"].alpha(t))(0.3)
    assert float(slope) == pytest.approx(-0.5 / 0.9, rel=1e-5)


def test_default_key_is_fixed(library):
    random = library["random"]
    np.testing.assert_array_equal(random.phase_alphas(100), random.phase_alphas(100, jax.random.key(0)))
    np.testing.assert_array_equal(random.alpha(0.37), random.alpha(0.37, jax.random.key(0)))


def test_raw_uint32_keys_work_too(library):
    random = library["random"]
    values = random.phase_alphas(100, jax.random.PRNGKey(5))
    assert values.shape == (100,)


@pytest.mark.parametrize(
    "call, error, message",
    [
        (lambda s: s.phase_values(10, channels=()), ValueError, "channels is empty"),
        (lambda s: s.phase_values(10, channels="mass"), TypeError, "for one channel write ('mass',)"),
        (lambda s: s.phase_values(10, channels=("mass", "mass")), ValueError, "names mass twice"),
        (lambda s: s.phase_value(3, 10, channels="gear"), TypeError, "a sequence of channels"),
        (lambda s: s.curve(None), TypeError, "a channel is a Channel or its name"),
        (lambda s: s.curve("strength"), ValueError, "'strength' is not a channel"),
        (lambda s: s.final_differences("leg-damage"), TypeError, "takes a Schedule"),
        (lambda s: s.phase_values(10, key=123), TypeError, "key is one JAX random key"),
        (lambda s: s.alpha(0.5, key=np.zeros(3)), TypeError, "not an array of float64[3]"),
        (lambda s: s.phase_alphas(10, key=jax.random.split(jax.random.key(0))), TypeError, "one JAX random key"),
    ],
)
def test_wrong_arguments_get_a_clear_error_saying_what_to_pass(library, call, error, message):
    with pytest.raises(error) as caught:
        call(library["growth"])
    assert message in str(caught.value)


def test_phase_alpha_compiles_once_for_every_phase(library):
    human = library["human"]
    phase_alpha = jax.jit(lambda k: human.phase_alpha(k, 100))
    values = [float(phase_alpha(k)) for k in range(100)]
    assert phase_alpha._cache_size() == 1
    np.testing.assert_allclose(values, human.phase_alphas(100), rtol=1e-6)


@pytest.mark.slow  # compiles every bundled schedule's phase table at four phase counts
def test_phase_alpha_is_the_curve_at_the_phase_start(library):
    for schedule in library.values():
        for phases in (7, 10, 100, 128):
            key = jax.random.key(1)
            at_starts = schedule.alpha(jnp.arange(phases) / phases, key)
            np.testing.assert_allclose(schedule.phase_alphas(phases, key), at_starts, rtol=1e-6)


def test_num_phases_must_be_a_positive_int(library):
    for bad in (0, -1, 2.5, True):
        with pytest.raises(ValueError):
            library["smol"].phase_alphas(bad)


def test_optax_style_schedule(library):
    smooth = library["smol"].as_optax(1000)
    stepped = library["smol"].as_optax(1000, num_phases=100)
    assert float(smooth(0)) == 1.5
    assert float(smooth(450)) == pytest.approx(1.25)
    assert float(stepped(455)) == float(stepped(450)) == pytest.approx(1.25)
    assert float(stepped(950)) == 1.0
    assert float(jax.jit(stepped)(jnp.asarray(999))) == 1.0
    with pytest.raises(ValueError):
        library["smol"].as_optax(0)


def test_certificate_is_json_ready(library):
    for schedule in library.values():
        for channel, certificate in schedule.certificates.items():
            data = certificate.to_dict()
            assert json.loads(json.dumps(data)) == data
            assert data["channel"] == channel.name
            assert math.isclose(data["tail_start"], float(schedule.curve(channel).tail_start))
        assert float(schedule.tail_start) == max(c.tail_start for c in schedule.certificates.values())


def test_symbolic_form_is_a_piecewise_of_t(library):
    from smol_dsl.language.symbolic import T

    expr = library["smol"].symbolic
    assert float(expr.subs(T, 0)) == 1.5
    assert float(expr.subs(T, 0.95)) == 1.0
    assert expr.free_symbols == {T}


def test_repr_is_informative(library):
    text = repr(library["human"])
    assert "SMOL-Human" in text and "tail from 90%" in text


def test_optax_phases_do_not_overflow_int32(library):
    stepped = library["smol"].as_optax(100_000_000, num_phases=100)
    assert float(stepped(95_000_000)) == 1.0
    assert float(stepped(21_474_837)) == pytest.approx(1.5 - 0.5 * 21 / 90)
    assert float(stepped(89_999_999)) == pytest.approx(1.5 - 0.5 * 89 / 90)
    with pytest.raises(ValueError):
        library["smol"].as_optax(2**31, num_phases=100)
    assert float(library["smol"].as_optax(2**31 - 1, num_phases=100)(2**31 - 2)) == 1.0


def test_roots_at_a_segment_edge_stay_finite_under_rounding():
    # sqrt(u) is exactly 0 at the segment's start; float32 rounding of u there must not give NaN
    schedule = smol_dsl.parse(
        "0 .. 0.005: constant 0.3\n0.005 .. 0.65: expr 1.305 + (0.3 - 1.305) * sqrt(u)\n0.65 .. 1: tail\n"
    )
    t = jnp.asarray([0.005, np.nextafter(np.float32(0.005), np.float32(1)), 0.3, 0.65], dtype=jnp.float32)
    values = np.asarray(schedule.alpha(t))
    assert np.all(np.isfinite(values)), values
    assert values[0] == pytest.approx(1.305, abs=1e-3)
    assert np.all(np.isfinite(np.asarray(schedule.phase_alphas(200))))
