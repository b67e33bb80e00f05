"""Property tests: every invariant the `.sched` language promises, on generated schedules.

Schedules come from `strategies.valid_schedules()` together with the ground truth they were
built from; nothing here trusts smol_dsl to say what a schedule should be.

JAX evaluates in float32, so values are compared with RTOL / ATOL, and points that a float32 t
could put on either side of a boundary (within NEAR_EDGE of it, but not on it) are skipped.
Arrays handed to JAX keep fixed shapes, so that op-by-op evaluation is compiled once per shape.
"""

from __future__ import annotations

import math
from fractions import Fraction
from itertools import combinations, pairwise

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sympy as sp
from budget import examples
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from strategies import (
    ALL_KINDS,
    CHEAP_KINDS,
    EASINGS,
    NO_BELLS,
    ONE_SHAPES,
    MultiChannelSpec,
    ScheduleSpec,
    invalid_multi_channel_schedules,
    invalid_schedules,
    multi_channel_schedules,
    random_segment_schedules,
    valid_schedules,
)
from sympy.core.function import AppliedUndef

import smol_dsl
from smol_dsl import Anatomy, Channel
from smol_dsl.language.symbolic import T

RTOL, ATOL = 1e-4, 1e-5  # float32 evaluation against exact values
NEAR_EDGE = Fraction(1, 10**6)  # float32 t this close to a boundary may land on either side of it

COMMON = dict(
    deadline=None,
    report_multiple_bugs=False,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
RANDOM_HEAVY = {**CHEAP_KINDS, "random": 6}
MONOTONE_KINDS = {**ALL_KINDS, "constant": 1, "random": 1}

seeds = st.integers(0, 2**31 - 1)
phase_counts = st.sampled_from((10, 16, 20, 40, 50, 64, 100, 200))

_compiled: dict[str, smol_dsl.Schedule] = {}


def compile_spec(spec: ScheduleSpec) -> smol_dsl.Schedule:
    """Parse a generated (valid) schedule; it must parse. Cached: verification takes seconds."""
    text = spec.text
    if text not in _compiled:
        _compiled[text] = smol_dsl.parse(text)
    return _compiled[text]


def key_of(seed: int) -> jax.Array:
    return jax.random.key(seed)


def close(actual, expected, rtol: float = RTOL, atol: float = ATOL) -> bool:
    actual, expected = np.asarray(actual, np.float64), np.asarray(expected, np.float64)
    return bool(np.all(np.abs(actual - expected) <= atol + rtol * np.abs(expected)))


def grid(n: int) -> np.ndarray:
    return np.linspace(0.0, 1.0, n, dtype=np.float32)


def clean(spec: ScheduleSpec, points: np.ndarray) -> np.ndarray:
    """Mask of the float32 points that do not straddle a boundary: not near (but not on) a
    segment boundary, nor near a random bin edge (alpha counts t up to 1e-4 bins below an edge
    as on it)."""
    boundaries = spec.boundaries()
    edges = [(edge, max(NEAR_EDGE, every / 5000)) for edge, every in spec.random_edges()]
    mask = []
    for x in points:
        t = Fraction(float(x))
        near_boundary = any(0 < abs(t - b) < NEAR_EDGE for b in boundaries)
        near_bin_edge = any(0 < abs(t - edge) < margin for edge, margin in edges)
        mask.append(not (near_boundary or near_bin_edge))
    return np.asarray(mask, dtype=bool)


def span_points(start: Fraction, end: Fraction, n: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """n float32 points over [start, end], and the mask of those inside [start, end) that are
    not within NEAR_EDGE of either end (the start itself is kept)."""
    points = np.linspace(float(start), float(end), n, dtype=np.float32)
    exact = [Fraction(float(x)) for x in points]
    mask = np.asarray([(t == start or t >= start + NEAR_EDGE) and t < end - NEAR_EDGE for t in exact], dtype=bool)
    return points, mask


def draws_of(schedule: smol_dsl.Schedule, key: jax.Array) -> list[np.ndarray | None]:
    return [None if d is None else np.asarray(d) for d in schedule.draws(key)]


def sympy_alpha(schedule: smol_dsl.Schedule, t: Fraction, draws: list[np.ndarray | None]) -> float:
    """alpha(t) from the sympy Piecewise at exact t, each random draw u_j(k) replaced by the
    value `Schedule.draws` gives it."""
    value = schedule.symbolic.subs(T, sp.Rational(t.numerator, t.denominator))

    def draw(call: AppliedUndef) -> sp.Expr:
        name = call.func.__name__
        assert name.startswith("u_"), name
        j = int(name[2:]) - 1  # u_j belongs to segment j, counted from 1
        assert draws[j] is not None, f"{name} names segment {j + 1}, which is not random"
        k = int(call.args[0])
        assert 0 <= k < len(draws[j]), f"{name}({k}) is outside its {len(draws[j])} draws"
        return sp.Rational(float(draws[j][k]))

    value = value.replace(lambda e: isinstance(e, AppliedUndef), draw)
    return float(sp.N(value, 30))


def monotone_on(values: np.ndarray, way: str) -> bool:
    values = np.asarray(values, np.float64)
    steps = np.diff(values)
    slack = ATOL + RTOL * np.abs(values[1:])
    return bool(np.all(steps >= -slack) if way == "increasing" else np.all(steps <= slack))


# ----------------------------------------------------------------------------- coverage


@settings(max_examples=examples(10), **COMMON)
@given(valid_schedules())
def test_valid_schedules_parse_and_tile_the_run(spec: ScheduleSpec):
    schedule = compile_spec(spec)
    segments = schedule.segments
    assert len(segments) == len(spec.segments)
    assert segments[0].start == 0
    assert segments[-1].end == 1
    for before, after in pairwise(segments):
        assert before.end == after.start  # no gap, no overlap, in exact arithmetic
    for got, want in zip(segments, spec.segments):
        assert isinstance(got.start, sp.Rational) and isinstance(got.end, sp.Rational)
        assert (Fraction(int(got.start.p), int(got.start.q)), Fraction(int(got.end.p), int(got.end.q))) == (
            want.start,
            want.end,
        )
        assert got.kind == want.kind
        assert got.monotone == want.declared
        assert len(got.pieces) == len(want.pieces)
        assert (got.draws is not None) == (want.random is not None)
        if want.random is not None:
            assert got.draws.count == want.random.count
            assert Fraction(int(got.draws.every.p), int(got.draws.every.q)) == want.random.every
    assert schedule.tail_start == spec.tail_start
    assert schedule.extinction == (0.0 if spec.extinction is None else float(spec.extinction[1]))
    assert schedule.name == (spec.name or "schedule")
    assert schedule.description == (spec.description or "")
    if spec.bounds is None:
        assert schedule.certificate.bounds is None
    else:
        assert schedule.certificate.bounds == (float(spec.bounds[2]), float(spec.bounds[3]))
    assert len(schedule.certificate.joins) == len(spec.segments) - 1


# ----------------------------------------------------------------------------- JAX == sympy


@settings(max_examples=examples(10), **COMMON)
@given(valid_schedules(declare=False), seeds, st.lists(st.floats(0, 1, width=32), min_size=7, max_size=7))
def test_jax_alpha_agrees_with_the_sympy_piecewise(spec: ScheduleSpec, seed: int, extra: list[float]):
    schedule = compile_spec(spec)
    key = key_of(seed)
    draws = draws_of(schedule, key)
    points = np.concatenate([grid(33), np.asarray(extra, np.float32)])
    values = np.asarray(schedule.alpha(jnp.asarray(points), key))
    assert values.shape == points.shape and values.dtype == np.float32
    for x, got in zip(points[clean(spec, points)], values[clean(spec, points)]):
        want = sympy_alpha(schedule, Fraction(float(x)), draws)
        assert close(got, want), f"alpha({float(x)!r}) = {got} in JAX but {want} in sympy"
    # the same values from a scalar t, under jit, and under vmap
    for i in (0, 16, 32, 35):
        assert float(schedule.alpha(float(points[i]), key)) == values[i]
    jitted = jax.jit(schedule.alpha)(jnp.asarray(points), key)
    assert close(jitted, values, rtol=1e-6, atol=1e-7)
    mapped = jax.jit(jax.vmap(schedule.alpha, in_axes=(0, None)))(jnp.asarray(points), key)
    assert close(mapped, values, rtol=1e-6, atol=1e-7)


@settings(max_examples=examples(10), **COMMON)
@given(valid_schedules(declare=False), seeds)
def test_alpha_follows_the_definition_of_each_shape(spec: ScheduleSpec, seed: int):
    """alpha(t) against the ground truth: each shape's documented formula, in float64."""
    schedule = compile_spec(spec)
    key = key_of(seed)
    draws = draws_of(schedule, key)
    points = grid(201)
    mask = clean(spec, points)
    values = np.asarray(schedule.alpha(jnp.asarray(points), key), np.float64)[mask]
    want = np.asarray([spec.alpha(float(x), draws) for x in points[mask]])
    bad = ~(np.abs(values - want) <= ATOL + RTOL * np.abs(want))
    assert not bad.any(), list(zip(points[mask][bad].tolist(), values[bad].tolist(), want[bad].tolist()))[:5]
    # t outside [0, 1] is clipped
    assert float(schedule.alpha(-0.5, key)) == float(schedule.alpha(0.0, key))
    assert float(schedule.alpha(1.5, key)) == float(schedule.alpha(1.0, key))


# ----------------------------------------------------------------------------- the certificate


@settings(max_examples=examples(10), **COMMON)
@given(valid_schedules(), seeds, phase_counts)
def test_certificate_bounds_every_alpha_and_alpha_is_positive(spec: ScheduleSpec, seed: int, n: int):
    schedule = compile_spec(spec)
    cert = schedule.certificate
    key = key_of(seed)
    assert 0 < cert.minimum <= cert.maximum
    values = np.asarray(schedule.alpha(jnp.asarray(grid(2001)), key), np.float64)
    phases = np.asarray(schedule.phase_alphas(n, key), np.float64)
    for sample in (values, phases):
        assert np.all(sample > 0)
        slack = ATOL + RTOL * np.abs(sample)
        assert np.all(sample >= cert.minimum - slack), (sample.min(), cert.minimum)
        assert np.all(sample <= cert.maximum + slack), (sample.max(), cert.maximum)
    # the certified range contains the true range and, where every piece is exact, is it
    assert cert.minimum <= float(spec.low) + 1e-9 and cert.maximum >= float(spec.high) - 1e-9
    if all(p.exact for p in cert.pieces):
        assert math.isclose(cert.minimum, float(spec.low), abs_tol=1e-9)
        assert math.isclose(cert.maximum, float(spec.high), abs_tol=1e-9)
    # one certified piece per true piece (a bell has two), each bounding alpha on its interval
    assert len(cert.pieces) == len(spec.pieces)
    for piece, (j, true) in zip(cert.pieces, spec.pieces):
        assert piece.segment == j + 1
        assert (piece.start, piece.end) == (float(true.start), float(true.end))
        assert piece.minimum <= float(true.low) + 1e-9 and piece.maximum >= float(true.high) - 1e-9, (piece, true)
        if piece.exact:
            assert math.isclose(piece.minimum, float(true.low), abs_tol=1e-9), (piece, true)
            assert math.isclose(piece.maximum, float(true.high), abs_tol=1e-9), (piece, true)
        points, mask = span_points(true.start, true.end)
        local = np.asarray(schedule.alpha(jnp.asarray(points), key), np.float64)[mask & clean(spec, points)]
        slack = ATOL + RTOL * np.abs(local)
        assert np.all(local >= piece.minimum - slack) and np.all(local <= piece.maximum + slack), piece
    # joins: continuous exactly where the truth is
    for i, join in enumerate(cert.joins):
        before, after = spec.segments[i], spec.segments[i + 1]
        assert join.position == float(after.start)
        if before.last is not None and after.first is not None:
            assert join.continuous == (before.last == after.first), join
            assert math.isclose(join.jump, float(after.first - before.last), abs_tol=1e-9), join
        else:
            assert not join.continuous and join.jump is None, join


# ----------------------------------------------------------------------------- the tail


@settings(max_examples=examples(10), **COMMON)
@given(valid_schedules(kinds=NO_BELLS), seeds, phase_counts)
def test_alpha_is_exactly_one_in_the_tail(spec: ScheduleSpec, seed: int, n: int):
    schedule = compile_spec(spec)
    key = key_of(seed)
    start = schedule.tail_start
    assert isinstance(start, Fraction) and start == spec.tail_start
    assert start <= Fraction(9, 10)
    assert schedule.certificate.tail_start == float(start)
    # float32 points t >= tail_start exactly: a grid, the first float32 at or after the start, 1
    first = np.float32(float(start))
    if Fraction(float(first)) < start:
        first = np.nextafter(first, np.float32(2))
    points = np.concatenate([grid(1001), [first, np.float32(1)]]).astype(np.float32)
    in_tail = np.asarray([Fraction(float(x)) >= start for x in points])
    values = np.asarray(schedule.alpha(jnp.asarray(points), key))[in_tail]
    off = values != 1.0
    assert not off.any(), list(zip(points[in_tail][off].tolist(), values[off].tolist()))[:5]
    phases = np.asarray(schedule.phase_alphas(n, key))
    tail = [k for k in range(n) if Fraction(k, n) >= start]
    assert all(phases[k] == 1.0 for k in tail), [(k, float(phases[k])) for k in tail if phases[k] != 1.0]
    assert schedule.tail_phases(n) == len(tail)


@pytest.mark.parametrize("shape", sorted(set(ONE_SHAPES)))
def test_every_form_of_an_alpha_one_tail_is_exactly_one(shape):
    """Each way of writing alpha == 1 that counts towards the tail evaluates to exactly 1.0."""
    tail = shape.format(one="1", mid="75%")
    schedule = smol_dsl.parse(f"0% .. 50%: constant 1.5\n50% .. 100%: {tail}\n")
    assert schedule.tail_start == Fraction(1, 2)
    values = np.asarray(schedule.alpha(jnp.asarray(np.linspace(0.5, 1.0, 501, dtype=np.float32))))
    assert np.all(values == 1.0), sorted(set(values.tolist()))
    assert np.all(np.asarray(schedule.phase_alphas(100))[50:] == 1.0)


# ----------------------------------------------------------------------------- declared properties


@settings(max_examples=examples(10), **COMMON)
@given(valid_schedules(kinds=NO_BELLS, bounds=True), seeds, phase_counts)
def test_declared_bounds_hold(spec: ScheduleSpec, seed: int, n: int):
    assert spec.bounds is not None
    low, high = float(spec.bounds[2]), float(spec.bounds[3])
    schedule = compile_spec(spec)
    key = key_of(seed)
    assert schedule.certificate.bounds == (low, high)
    assert low <= schedule.certificate.minimum and schedule.certificate.maximum <= high
    values = np.asarray(schedule.alpha(jnp.asarray(grid(2001)), key), np.float64)
    phases = np.asarray(schedule.phase_alphas(n, key), np.float64)
    for sample in (values, phases):
        slack = ATOL + RTOL * np.abs(sample)
        assert np.all(sample >= low - slack) and np.all(sample <= high + slack), (sample.min(), sample.max())


@settings(max_examples=examples(10), **COMMON)
@given(valid_schedules(kinds=MONOTONE_KINDS), seeds)
def test_declared_and_certified_monotone_segments_are_monotone(spec: ScheduleSpec, seed: int):
    schedule = compile_spec(spec)
    key = key_of(seed)
    for j, segment in enumerate(spec.segments):
        if segment.declared is not None:
            points, mask = span_points(segment.start, segment.end, 200)
            values = np.asarray(schedule.alpha(jnp.asarray(points), key))[mask & clean(spec, points)]
            assert monotone_on(values, segment.declared), (j, segment.shape, segment.declared, values)
    # what the certificate calls monotone is monotone, in truth and on a grid
    for piece, (_, true) in zip(schedule.certificate.pieces, spec.pieces):
        if piece.monotone in ("increasing", "decreasing"):
            assert piece.monotone in true.allowed, (piece, true)
            points, mask = span_points(true.start, true.end, 200)
            values = np.asarray(schedule.alpha(jnp.asarray(points), key))[mask & clean(spec, points)]
            assert monotone_on(values, piece.monotone), piece
        elif piece.monotone == "neither":
            assert not true.allowed, (piece, true)
        elif piece.monotone == "constant":
            assert true.low == true.high, (piece, true)


@pytest.mark.parametrize("way", ["increasing", "decreasing"])
@pytest.mark.parametrize("easing", sorted(EASINGS))
def test_true_monotone_declarations_of_easings_are_proven(easing, way):
    """`expr a + (b - a) * EASE(u)` with a monotone easing is monotone; declared so, it verifies."""
    a, b = ("0.67", "1") if way == "increasing" else ("1.3", "1")
    body = f"{a} + ({b} - {a}) * {EASINGS[easing][0]}"
    schedule = smol_dsl.parse(f"0% .. 46%: constant {a}\n46% .. 59%: expr {body} {way}\n59% .. 100%: tail\n")
    assert schedule.certificate.pieces[1].monotone == way


# ----------------------------------------------------------------------------- discretisation


@settings(max_examples=examples(10), **COMMON)
@given(valid_schedules(kinds=NO_BELLS, declare=False), seeds, phase_counts)
def test_phase_alphas_sample_alpha_at_phase_starts(spec: ScheduleSpec, seed: int, n: int):
    schedule = compile_spec(spec)
    key = key_of(seed)
    phases = np.asarray(schedule.phase_alphas(n, key))
    assert phases.shape == (n,)
    starts = np.asarray([k / n for k in range(n)], dtype=np.float32)  # k/N rounded once, to nearest
    sampled = np.asarray(schedule.alpha(jnp.asarray(starts), key))
    wrong = [(k, float(phases[k]), float(sampled[k])) for k in range(n) if not close(phases[k], sampled[k])]
    assert not wrong, wrong[:5]
    draws = draws_of(schedule, key)
    truth = [spec.alpha(Fraction(k, n), draws) for k in range(n)]
    wrong = [(k, float(phases[k]), truth[k]) for k in range(n) if not close(phases[k], truth[k])]
    assert not wrong, wrong[:5]
    assert np.array_equal(np.asarray(schedule.phase_alphas(n, None)), np.asarray(schedule.phase_alphas(n, key_of(0))))


@settings(max_examples=examples(8), **COMMON)
@given(valid_schedules(kinds=CHEAP_KINDS, declare=False), seeds, phase_counts, st.data())
def test_phase_alpha_is_one_compiled_function_of_a_traced_phase(spec: ScheduleSpec, seed: int, n: int, data):
    schedule = compile_spec(spec)
    key = key_of(seed)
    phases = np.asarray(schedule.phase_alphas(n, key))
    traces = []

    def phase(k):
        traces.append(k)
        return schedule.phase_alpha(k, n, key)

    jitted = jax.jit(phase)
    ks = data.draw(st.lists(st.integers(0, n - 1), min_size=3, max_size=8))
    for k in [0, n - 1, *ks]:
        # compiled and op-by-op float32 may differ in the last bits (fused multiply-adds)
        assert close(jitted(jnp.int32(k)), phases[k], rtol=1e-6, atol=1e-7), k
    assert len(traces) == 1, "phase_alpha was traced again for another k"
    assert isinstance(traces[0], jax.core.Tracer)
    assert close(jax.vmap(jitted)(jnp.arange(n, dtype=jnp.int32)), phases, rtol=1e-6, atol=1e-7)


# ----------------------------------------------------------------------------- random segments


@settings(max_examples=examples(10), **COMMON)
@given(valid_schedules(kinds=RANDOM_HEAVY, declare=False), seeds, seeds, phase_counts)
def test_random_segments_are_a_function_of_the_key(spec: ScheduleSpec, seed: int, other: int, n: int):
    schedule = compile_spec(spec)
    points = jnp.asarray(grid(301))
    for evaluate in (lambda key: schedule.phase_alphas(n, key), lambda key: schedule.alpha(points, key)):
        assert np.array_equal(np.asarray(evaluate(key_of(seed))), np.asarray(evaluate(key_of(seed))))
    first, again = draws_of(schedule, key_of(seed)), draws_of(schedule, key_of(seed))
    different = draws_of(schedule, key_of(other))
    for i, (segment, a, b, c) in enumerate(zip(spec.segments, first, again, different)):
        assert (segment.random is None) == (a is None) == (b is None) == (c is None)
        if segment.random is not None:
            assert a.shape == c.shape == (segment.random.count,)
            assert np.array_equal(a, b)
            # the documented stream: uniform(fold_in(key, i), (count,)), i the 0-based segment position
            stream = jax.random.uniform(jax.random.fold_in(key_of(seed), i), (segment.random.count,))
            assert np.array_equal(a, np.asarray(stream))
            # independent uniform float32 draws coincide with probability about 2**-23 each
            assert seed == other or not np.array_equal(a, c)


@settings(max_examples=examples(10), **COMMON)
@given(valid_schedules(kinds=RANDOM_HEAVY, declare=False), seeds, phase_counts)
def test_random_values_lie_in_their_range(spec: ScheduleSpec, seed: int, n: int):
    schedule = compile_spec(spec)
    key = key_of(seed)
    points = grid(1001)
    usable = clean(spec, points)
    values = np.asarray(schedule.alpha(jnp.asarray(points), key), np.float64)
    phases = np.asarray(schedule.phase_alphas(n, key), np.float64)
    draws = draws_of(schedule, key)
    for j, segment in enumerate(spec.segments):
        if segment.random is None:
            continue
        assert np.all((draws[j] >= 0) & (draws[j] < 1))
        low, high = float(segment.random.low), float(segment.random.high)
        here = usable & np.asarray([spec.segment_at(Fraction(float(x))) == j for x in points])
        ours = np.asarray([spec.segment_at(Fraction(k, n)) == j for k in range(n)])
        for sample in (values[here], phases[ours]):
            slack = 1e-6 * high
            assert np.all(sample >= low - slack) and np.all(sample <= high + slack), (low, high, sample)


@settings(max_examples=examples(10), **COMMON)
@given(random_segment_schedules(), seeds)
def test_random_segments_draw_one_value_per_step(case: tuple[ScheduleSpec, int], seed: int):
    spec, n = case
    schedule = compile_spec(spec)
    key = key_of(seed)
    phases = np.asarray(schedule.phase_alphas(n, key))
    (j,) = [i for i, s in enumerate(spec.segments) if s.random is not None]
    segment = spec.segments[j]
    r = segment.random
    draws = np.asarray(schedule.draws(key)[j])
    assert draws.shape == (r.count,)
    ks = [k for k in range(n) if segment.start <= Fraction(k, n) < segment.end]
    bins = [math.floor((Fraction(k, n) - segment.start) / r.every) for k in ks]
    # every phase shows the draw of its step, and a new step brings a new value
    for k, b in zip(ks, bins):
        assert close(phases[k], float(r.low) + float(r.high - r.low) * float(draws[b])), (k, b)
    if r.low < r.high:
        for (k0, b0), (k1, b1) in pairwise(zip(ks, bins)):
            assert (phases[k0] == phases[k1]) == (b0 == b1), (k0, k1, b0, b1)
        assert len(set(bins)) == r.count  # every step is shown
        shown = dict(zip(bins, phases[ks].tolist(), strict=True))
        # two steps show one value only where float32 rounds their draws to it (a narrow range
        # near 1.6 holds some 40 000 float32 values: 38 draws collide 2% of the time)
        resolution = 4 * float(np.spacing(np.float32(max(abs(r.low), abs(r.high)))))
        for b0, b1 in combinations(shown, 2):
            if shown[b0] == shown[b1]:
                assert abs(float(draws[b0]) - float(draws[b1])) * float(r.high - r.low) <= resolution, (b0, b1)


@settings(max_examples=examples(6), **COMMON)
@given(
    st.sampled_from(("", " every 1%", " every 0.01", " every 1/100")),
    st.integers(10, 200),
    st.integers(0, 100),
    seeds,
)
def test_a_one_percent_random_segment_over_90_percent_gives_90_values_in_100_phases(every, lo, extra, seed):
    low, high = lo / 100, (lo + 1 + extra) / 100
    schedule = smol_dsl.parse(f"0% .. 90%: random {low} .. {high}{every}\n90% .. 100%: tail\n")
    phases = np.asarray(schedule.phase_alphas(100, key_of(seed)))
    body = phases[:90]
    assert len(set(body.tolist())) == 90
    assert np.all(body[1:] != body[:-1])  # the draw changes at every phase
    assert np.all((body >= np.float32(low)) & (body <= np.float32(high)))
    assert np.all(phases[90:] == 1.0)


# ----------------------------------------------------------------------------- invalid schedules


def refusal(case) -> smol_dsl.ScheduleError:
    """The ScheduleError an invalid case raises; anything else, or acceptance, fails the test."""
    try:
        smol_dsl.parse(case.text, path="case.sched")
    except smol_dsl.ScheduleError as error:
        return error
    except Exception as error:  # anything else is a bug
        pytest.fail(f"{case.rule}: {type(error).__name__}: {error}\n{case.text}")
    pytest.fail(f"{case.rule}: accepted\n{case.text}")


@settings(max_examples=examples(60), **COMMON)
@given(invalid_schedules())
def test_invalid_schedules_raise_one_located_schedule_error(case):
    event(case.rule.partition(":")[0])
    caught = refusal(case)
    assert caught.line is not None and caught.line >= 1, case.rule
    assert caught.column is not None and caught.column >= 1, case.rule
    assert caught.hint, case.rule
    shown = str(caught)
    assert shown.startswith(f"case.sched:{caught.line}:{caught.column}: error: "), shown
    assert f"\nhint: {caught.hint}" in shown
    if case.line is not None:
        assert caught.line == case.line, (case.rule, shown, case.text)
    if case.message is not None:
        assert case.message in caught.message, (case.rule, caught.message)


# ----------------------------------------------------------------------------- multi-channel schedules


def channel_of(spec) -> Channel:
    return Channel(spec.kind, spec.targets)


def random_draws_of(schedule: smol_dsl.Schedule, channel: Channel, key: jax.Array) -> list[np.ndarray | None]:
    return [None if d is None else np.asarray(d) for d in schedule.curve(channel).draws(key)]


@settings(max_examples=examples(12), **COMMON)
@given(multi_channel_schedules(), seeds, phase_counts)
def test_every_channel_is_verified_and_evaluated_against_its_truth(multi: MultiChannelSpec, seed: int, n: int):
    schedule = smol_dsl.parse(multi.text)
    channels = tuple(channel_of(c) for c in multi.channels)
    assert schedule.channels == channels
    assert schedule.final_body == {channel_of(c): float(c.final) for c in multi.channels}
    assert schedule.tail_start == multi.tail_start
    assert schedule.extinction == (0.0 if multi.extinction is None else float(multi.extinction[1]))
    key = key_of(seed)
    values = np.asarray(schedule.checked_phase_values(n, key))
    assert values.shape == (n, len(channels)) and values.dtype == np.float32
    assert np.all(np.isfinite(values)) and np.all(values > 0)
    for column, (channel, truth) in enumerate(zip(channels, multi.channels)):
        body = truth.body
        certificate = schedule.certificates[channel]
        assert certificate.channel == channel and certificate.final == float(truth.final)
        assert certificate.minimum == pytest.approx(float(body.low), abs=1e-9)
        assert certificate.maximum == pytest.approx(float(body.high), abs=1e-9)
        assert certificate.tail_start == float(body.tail_start)
        assert f"tail: {channel.quantity} == {float(truth.final):g} from" in str(certificate)
        curve = schedule.curve(channel)
        assert curve.tail_start == body.tail_start and curve.final == float(truth.final)
        # each channel is exactly its final value over its tail, from the first phase wholly in it
        in_tail = np.asarray([Fraction(k, n) >= body.tail_start for k in range(n)])
        assert np.all(values[in_tail, column] == np.float32(truth.final)), values[:, column]
        # and its documented value at every phase start
        draws = random_draws_of(schedule, channel, key)
        want = [body.alpha(Fraction(k, n), draws) for k in range(n)]
        assert close(values[:, column], want), (channel.name, values[:, column], want)


@settings(max_examples=examples(10), **COMMON)
@given(multi_channel_schedules(), st.data(), seeds)
def test_declaration_order_does_not_change_any_value(multi: MultiChannelSpec, data, seed: int):
    order = data.draw(st.permutations(range(len(multi.channels))))
    first = smol_dsl.parse(multi.text)
    second = smol_dsl.parse(multi.reordered(order).text)
    assert second.channels == tuple(first.channels[i] for i in order)
    key = key_of(seed)
    for n in (10, 64):
        a = np.asarray(first.phase_values(n, key, first.channels))
        b = np.asarray(second.phase_values(n, key, first.channels))
        assert a.tobytes() == b.tobytes()
    assert first.certificates == second.certificates


@settings(max_examples=examples(10), **COMMON)
@given(valid_schedules(kinds=CHEAP_KINDS), seeds, phase_counts)
def test_one_channel_files_equal_their_gear_only_form(spec: ScheduleSpec, seed: int, n: int):
    plain = compile_spec(spec)
    explicit = smol_dsl.parse("channel gear\n" + spec.text)
    assert plain.channels == explicit.channels == (smol_dsl.GEAR,)
    assert str(plain.certificate) == str(explicit.certificate)
    key = key_of(seed)
    values = plain.checked_phase_values(n, key)
    assert values[:, 0].tobytes() == plain.checked_phase_alphas(n, key).tobytes()
    assert explicit.checked_phase_values(n, key).tobytes() == values.tobytes()


@settings(max_examples=examples(10), **COMMON)
@given(multi_channel_schedules(max_body=1, targets=False))
def test_check_targets_needs_no_listing_of_a_body_when_no_channel_names_targets(multi: MultiChannelSpec):
    schedule = smol_dsl.parse(multi.text, path="m.sched")
    schedule.check_targets(Anatomy((), ()).targets(), "toy")
    schedule.check_targets(None, "toy")


@settings(max_examples=examples(10), **COMMON)
@given(multi_channel_schedules(max_body=1, targets=True), st.data())
def test_check_targets_accepts_exactly_the_bodies_that_have_every_target(multi: MultiChannelSpec, data):
    schedule = smol_dsl.parse(multi.text, path="m.sched")
    actuators = sorted({t for c in multi.channels if c.kind == "gear" for t in c.targets})
    links = sorted({t for c in multi.channels if c.kind == "mass" for t in c.targets})
    schedule.check_targets(Anatomy(tuple(actuators), tuple(links)).targets(), "toy")
    targeted = [c for c in multi.channels if c.targets]
    channel = data.draw(st.sampled_from(targeted))
    missing = data.draw(st.sampled_from(channel.targets))
    actuators = [a for a in actuators if a != missing or channel.kind != "gear"]
    links = [link for link in links if link != missing or channel.kind != "mass"]
    with pytest.raises(smol_dsl.ScheduleError) as caught:
        schedule.check_targets(Anatomy(tuple(actuators), tuple(links)).targets(), "toy")
    error = caught.value
    # the first channel, in declared order, that names a target the body lacks
    first = next(k for k, c in enumerate(multi.channels) if c.kind == channel.kind and missing in c.targets)
    assert error.line == multi.render()[1][f"{first}/channel"] and f"`{missing}`" in error.message
    assert str(error).startswith(f"m.sched:{error.line}:{error.column}: error: task toy has no ")
    with pytest.raises(smol_dsl.ScheduleError, match="does not list its"):
        schedule.check_targets(None, "toy")


@settings(max_examples=examples(40), **COMMON)
@given(invalid_multi_channel_schedules())
def test_invalid_multi_channel_files_raise_one_located_schedule_error(case):
    event(case.rule.partition(":")[0].rstrip("0123456789 "))
    caught = refusal(case)
    shown = str(caught)
    assert shown.startswith(f"case.sched:{caught.line}:{caught.column}: error: "), shown
    assert caught.hint and f"\nhint: {caught.hint}" in shown
    assert caught.line == case.line, (case.rule, shown, case.text)
    if case.message is not None:
        assert case.message in caught.message, (case.rule, caught.message)
