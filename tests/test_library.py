"""The bundled curricula give the paper's values at every phase of 100."""

from __future__ import annotations

from fractions import Fraction

import jax
import numpy as np
import pytest

PHASES = 100
TAIL_PHASE = 90  # the last 10% of training, phases 90..99, runs at alpha = 1


def test_library_has_every_condition_of_the_paper_and_the_channel_curricula(library):
    assert sorted(library) == [
        "extinction-05",
        "extinction-10",
        "extinction-50",
        "growth",
        "human",
        "human-paced",
        "leg-damage",
        "low-gravity",
        "random",
        "smol",
        "smol-paced",
        "smol-reverse",
        "vanilla",
    ]
    for schedule in library.values():
        assert schedule.name and schedule.description
        assert schedule.source.strip()


@pytest.mark.parametrize("name", ["vanilla", "extinction-05", "extinction-10", "extinction-50"])
def test_constant_schedules_are_one_at_every_phase(library, name):
    alphas = np.asarray(library[name].phase_alphas(PHASES))
    assert alphas.shape == (PHASES,)
    assert np.all(alphas == 1.0)
    assert library[name].tail_start == 0


@pytest.mark.parametrize(
    ("name", "probability"),
    [("vanilla", 0.0), ("extinction-05", 0.05), ("extinction-10", 0.10), ("extinction-50", 0.50)],
)
def test_extinction_probabilities(library, name, probability):
    assert library[name].extinction == pytest.approx(probability, abs=0)
    assert library[name].certificate.extinction == probability


@pytest.mark.parametrize(("name", "start"), [("smol", 1.5), ("smol-reverse", 0.5)])
def test_linear_schedules_match_the_paper(library, name, start):
    alphas = np.asarray(library[name].phase_alphas(PHASES))
    k = np.arange(TAIL_PHASE)
    expected = start + (1.0 - start) * k / TAIL_PHASE
    np.testing.assert_allclose(alphas[:TAIL_PHASE], expected, rtol=1e-6)
    assert alphas[0] == start
    assert np.all(alphas[TAIL_PHASE:] == 1.0)
    steps = np.diff(alphas[: TAIL_PHASE + 1])
    assert np.all(steps < 0) if start > 1 else np.all(steps > 0)


def _human_bell(t: np.ndarray) -> np.ndarray:
    """SMOL-Human written out independently in float64: 0.7 -> 1.4 at 30% -> 1.0 at 90%."""
    a, p, z, m, w, s, e = 0.7, 1.4, 1.0, 0.3, 0.15, 0.0, 0.9

    def g(x):
        return np.exp(-((x - m) ** 2) / (2 * w**2))

    rise = a + (p - a) * (g(t) - g(s)) / (1 - g(s))
    fall = z + (p - z) * (g(t) - g(e)) / (1 - g(e))
    return np.where(t < m, rise, fall)


def test_human_follows_the_bell_of_the_paper(library):
    human = library["human"]
    alphas = np.asarray(human.phase_alphas(PHASES))
    k = np.arange(TAIL_PHASE)
    np.testing.assert_allclose(alphas[:TAIL_PHASE], _human_bell(k / PHASES), rtol=1e-5)
    assert alphas[0] == pytest.approx(0.7, abs=1e-7)
    assert alphas.max() == pytest.approx(1.4, abs=1e-6)
    assert int(alphas.argmax()) == 30
    assert np.all(np.diff(alphas[:31]) > 0)
    assert np.all(np.diff(alphas[30:TAIL_PHASE]) < 0)
    assert np.all(alphas[TAIL_PHASE:] == 1.0)
    certificate = human.certificate
    assert (certificate.minimum, certificate.maximum) == pytest.approx((0.7, 1.4))
    assert [p.monotone for p in certificate.pieces] == ["increasing", "decreasing", "constant"]
    assert all(join.continuous for join in certificate.joins)


def test_random_draws_a_new_alpha_every_phase_then_one(library):
    schedule = library["random"]
    key = jax.random.key(7)
    alphas = np.asarray(schedule.phase_alphas(PHASES, key))
    head = alphas[:TAIL_PHASE]
    assert np.all((head >= 0.5) & (head <= 1.5))
    assert len(np.unique(head)) == TAIL_PHASE
    assert np.all(alphas[TAIL_PHASE:] == 1.0)
    # the same key gives the same schedule; another key another one
    np.testing.assert_array_equal(alphas, np.asarray(schedule.phase_alphas(PHASES, key)))
    other = np.asarray(schedule.phase_alphas(PHASES, jax.random.key(8)))
    assert not np.array_equal(head, other[:TAIL_PHASE])
    # the draws are per 1% of the run, not per phase: 200 phases see each draw twice
    fine = np.asarray(schedule.phase_alphas(200, key))
    np.testing.assert_array_equal(fine[: 2 * TAIL_PHASE : 2], head)
    np.testing.assert_array_equal(fine[1 : 2 * TAIL_PHASE : 2], head)


def test_random_draws_are_roughly_uniform(library):
    schedule = library["random"]
    values = np.concatenate(
        [np.asarray(schedule.phase_alphas(PHASES, jax.random.key(seed)))[:TAIL_PHASE] for seed in range(20)]
    )
    assert abs(values.mean() - 1.0) < 0.03
    assert values.min() < 0.53 and values.max() > 1.47


@pytest.mark.parametrize("name", ["smol", "smol-reverse", "human", "random"])
def test_tail_is_the_final_ten_percent(library, name):
    schedule = library[name]
    assert schedule.tail_start == Fraction(9, 10)
    assert schedule.certificate.tail_start == 0.9
    assert schedule.tail_phases(100) == 10
    assert schedule.tail_phases(10) == 1
    assert schedule.tail_phases(9) == 0


def test_library_certificates_respect_declared_bounds(library):
    for schedule in library.values():
        certificate = schedule.certificate
        assert certificate.minimum > 0
        if certificate.bounds is not None:
            low, high = certificate.bounds
            assert low <= certificate.minimum <= certificate.maximum <= high
