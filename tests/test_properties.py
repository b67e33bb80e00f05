"""Property tests: every invariant the `.sched` language promises, on generated schedules.

Schedules come from `strategies.valid_schedules()` together with the ground truth they were
built from; nothing here trusts smol_dsl to say what a schedule should be.
"""

from __future__ import annotations

import math
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sympy as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from strategies import (
    FAST_KINDS,
    KIND_WEIGHTS,
    ScheduleSpec,
    invalid_schedules,
    random_segment_schedules,
    valid_schedules,
)
from sympy.core.function import AppliedUndef

import smol_dsl
from smol_dsl.symbolic import T

RTOL, ATOL = 1e-4, 1e-5  # float32 evaluation against exact values
NEAR_EDGE = 1e-6  # float32 t this close to a segment boundary may land on either side

COMMON = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
RANDOM_HEAVY = {**FAST_KINDS, "random": 6}
MONOTONE_KINDS = {**KIND_WEIGHTS, "constant": 1, "random": 1}

seeds = st.integers(0, 2**31 - 1)
phase_counts = st.sampled_from((10, 16, 20, 40, 50, 64, 100, 200))

_compiled: dict[str, smol_dsl.Schedule] = {}


def compile_spec(spec: ScheduleSpec) -> smol_dsl.Schedule:
    """Parse a generated (valid) schedule; it must parse. Cached: verification is slow."""
    text = spec.text
    if text not in _compiled:
        _compiled[text] = smol_dsl.parse(text)
    return _compiled[text]


def key_of(seed: int) -> jax.Array:
    return jax.random.key(seed)


def close(actual, expected, rtol: float = RTOL, atol: float = ATOL) -> bool:
    return bool(np.all(np.abs(np.asarray(actual, np.float64) - expected) <= atol + rtol * np.abs(expected)))


def float32_grid(n: int) -> np.ndarray:
    return np.linspace(0.0, 1.0, n, dtype=np.float32)


def away_from_edges(spec: ScheduleSpec, points: np.ndarray) -> np.ndarray:
    """Drop float32 points that straddle a boundary: near (but not on) a segment boundary, or
    near a random segment's bin edge (alpha counts a point 1e-4 bins below an edge as on it)."""
    boundaries = spec.boundaries()
    edges = spec.random_edges()
    keep = []
    for x in points:
        t = Fraction(float(x))
        if any(0 < abs(t - b) < NEAR_EDGE for b in boundaries):
            continue
        if any(abs(t - edge) < max(NEAR_EDGE, 2e-4 * float(every)) and t != edge for edge, every in edges):
            continue
        keep.append(x)
    return np.asarray(keep, dtype=np.float32)


def draws_of(schedule: smol_dsl.Schedule, key: jax.Array) -> list[np.ndarray | None]:
    return [None if d is None else np.asarray(d) for d in schedule.draws(key)]


def sympy_alpha(schedule: smol_dsl.Schedule, t: Fraction, draws: list[np.ndarray | None]) -> float:
    """alpha(t) from the sympy Piecewise at exact t, with each random draw u_j(k) replaced by
    the value `Schedule.draws` gives it."""
    value = schedule.symbolic.subs(T, sp.Rational(t.numerator, t.denominator))

    def draw(call: AppliedUndef) -> sp.Expr:
        name = call.func.__name__
        assert name.startswith("u_"), name
        j = int(name[2:]) - 1
        segment_draws = draws[j]
        assert segment_draws is not None, f"{name} names segment {j + 1}, which is not random"
        k = int(call.args[0])
        assert 0 <= k < len(segment_draws), f"{name}({k}) outside its {len(segment_draws)} draws"
        return sp.Rational(float(segment_draws[k]))

    value = value.replace(lambda e: isinstance(e, AppliedUndef), draw)
    return float(sp.N(value, 30))


def monotone_on(values: np.ndarray, way: str) -> bool:
    steps = np.diff(np.asarray(values, np.float64))
    slack = ATOL + RTOL * np.abs(np.asarray(values[1:], np.float64))
    return bool(np.all(steps >= -slack) if way == "increasing" else np.all(steps <= slack))


def inside(spec_start: Fraction, spec_end: Fraction, n: int) -> np.ndarray:
    """float32 points inside [start, end) (exactly, as rationals), start included."""
    points = np.linspace(float(spec_start), float(spec_end), n, dtype=np.float32)
    return np.asarray(
        [x for x in points if spec_start <= Fraction(float(x)) < spec_end] or [np.float32(spec_start)],
        dtype=np.float32,
    )


# ----------------------------------------------------------------------------- coverage


@settings(max_examples=12, **COMMON)
@given(valid_schedules())
def test_valid_schedules_parse_and_tile_the_run(spec: ScheduleSpec):
    schedule = compile_spec(spec)
    segments = schedule.segments
    assert len(segments) == len(spec.segments)
    assert segments[0].start == 0
    assert segments[-1].end == 1
    for before, after in zip(segments, segments[1:]):
        assert before.end == after.start  # no gap, no overlap, exactly
    for got, want in zip(segments, spec.segments):
        assert (Fraction(int(got.start.p), int(got.start.q)), Fraction(int(got.end.p), int(got.end.q))) == (
            want.start,
            want.end,
        )
        assert got.kind == want.kind
        assert got.monotone == want.declared
        assert (got.random is not None) == (want.random is not None)
        if want.random is not None:
            assert got.random.count == want.random.count
            assert Fraction(int(got.random.every.p), int(got.random.every.q)) == want.random.every
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


@settings(max_examples=10, **COMMON)
@given(valid_schedules(declare=False), seeds, st.lists(st.floats(0, 1, width=32), max_size=8))
def test_jax_alpha_agrees_with_the_sympy_piecewise(spec: ScheduleSpec, seed: int, extra: list[float]):
    schedule = compile_spec(spec)
    key = key_of(seed)
    draws = draws_of(schedule, key)
    points = away_from_edges(spec, np.concatenate([float32_grid(33), np.asarray(extra, np.float32)]))
    values = np.asarray(schedule.alpha(jnp.asarray(points), key))
    assert values.shape == points.shape
    for x, got in zip(points, values):
        want = sympy_alpha(schedule, Fraction(float(x)), draws)
        assert close(got, want), f"alpha({float(x)!r}) = {got} in JAX but {want} in sympy"
    # the same values as a scalar, under jit and under vmap
    for i in range(0, len(points), max(1, len(points) // 4)):
        assert float(schedule.alpha(float(points[i]), key)) == values[i]
    jitted = jax.jit(schedule.alpha)(jnp.asarray(points), key)
    assert close(jitted, values.astype(np.float64), rtol=1e-6, atol=1e-7)
    mapped = jax.vmap(lambda t: schedule.alpha(t, key))(jnp.asarray(points))
    assert close(mapped, values.astype(np.float64), rtol=1e-6, atol=1e-7)


@settings(max_examples=10, **COMMON)
@given(valid_schedules(declare=False), seeds)
def test_alpha_follows_the_definition_of_each_shape(spec: ScheduleSpec, seed: int):
    """alpha(t) against the ground truth: each shape's documented formula, evaluated in float64."""
    schedule = compile_spec(spec)
    key = key_of(seed)
    draws = draws_of(schedule, key)
    points = away_from_edges(spec, float32_grid(201))
    values = np.asarray(schedule.alpha(jnp.asarray(points), key))
    want = np.asarray([spec.alpha(float(x), draws) for x in points])
    bad = ~(np.abs(values - want) <= ATOL + RTOL * np.abs(want))
    assert not bad.any(), [(float(x), float(g), float(w)) for x, g, w in zip(points[bad], values[bad], want[bad])][:5]
    # t outside [0, 1] is clipped
    assert float(schedule.alpha(-0.5, key)) == float(schedule.alpha(0.0, key))
    assert float(schedule.alpha(1.5, key)) == float(schedule.alpha(1.0, key))


# ----------------------------------------------------------------------------- the certificate


@settings(max_examples=10, **COMMON)
@given(valid_schedules(), seeds, phase_counts)
def test_certificate_bounds_every_alpha_and_alpha_is_positive(spec: ScheduleSpec, seed: int, n: int):
    schedule = compile_spec(spec)
    cert = schedule.certificate
    key = key_of(seed)
    assert 0 < cert.minimum <= cert.maximum
    values = np.asarray(schedule.alpha(jnp.asarray(float32_grid(2001)), key), np.float64)
    phases = np.asarray(schedule.phase_alphas(n, key), np.float64)
    for sample in (values, phases):
        assert np.all(sample > 0)
        slack = ATOL + RTOL * np.abs(sample)
        assert np.all(sample >= cert.minimum - slack), (sample.min(), cert.minimum)
        assert np.all(sample <= cert.maximum + slack), (sample.max(), cert.maximum)
    # the certificate's range is sound (contains the true range) and, where exact, tight
    assert cert.minimum <= float(spec.low) + 1e-9 and cert.maximum >= float(spec.high) - 1e-9
    if all(p.exact for p in cert.pieces):
        assert math.isclose(cert.minimum, float(spec.low), abs_tol=1e-9)
        assert math.isclose(cert.maximum, float(spec.high), abs_tol=1e-9)
    # each piece's bounds hold on the piece
    for piece in cert.pieces:
        segment = spec.segments[piece.segment - 1]
        assert (piece.minimum <= float(segment.low) + 1e-9 and piece.maximum >= float(segment.high) - 1e-9) or (
            segment.kind == "bell"  # a bell's pieces are its two halves
        )
        local = np.asarray(schedule.alpha(jnp.asarray(inside(Fraction(piece.start), Fraction(piece.end), 64)), key))
        slack = ATOL + RTOL * np.abs(local)
        assert np.all(local >= piece.minimum - slack) and np.all(local <= piece.maximum + slack), piece
    # joins: continuous exactly where the truth is
    for i, join in enumerate(cert.joins):
        before, after = spec.segments[i], spec.segments[i + 1]
        assert join.position == float(after.start)
        if before.last is not None and after.first is not None:
            assert join.continuous == (before.last == after.first), join
            assert math.isclose(join.jump, float(after.first - before.last), abs_tol=1e-9), join


# ----------------------------------------------------------------------------- the tail


@settings(max_examples=12, **COMMON)
@given(valid_schedules(kinds=FAST_KINDS), seeds, phase_counts)
def test_alpha_is_exactly_one_in_the_tail(spec: ScheduleSpec, seed: int, n: int):
    schedule = compile_spec(spec)
    key = key_of(seed)
    start = schedule.tail_start
    assert start == spec.tail_start
    assert start <= Fraction(9, 10)
    assert math.isclose(schedule.certificate.tail_start, float(start))
    points = [x for x in float32_grid(1001) if Fraction(float(x)) >= start]
    first = np.float32(float(start))
    if Fraction(float(first)) < start:
        first = np.nextafter(first, np.float32(2))
    points = np.asarray([first, *points, np.float32(1)], dtype=np.float32)
    values = np.asarray(schedule.alpha(jnp.asarray(points), key))
    off = values != 1.0
    assert not off.any(), list(zip(points[off].tolist(), values[off].tolist()))[:5]
    phases = np.asarray(schedule.phase_alphas(n, key))
    in_tail = [k for k in range(n) if Fraction(k, n) >= start]
    assert all(phases[k] == 1.0 for k in in_tail), [(k, float(phases[k])) for k in in_tail if phases[k] != 1.0]
    assert schedule.tail_phases(n) == len(in_tail)


# ----------------------------------------------------------------------------- declared properties


@settings(max_examples=10, **COMMON)
@given(valid_schedules(kinds=FAST_KINDS, bounds=True), seeds, phase_counts)
def test_declared_bounds_hold(spec: ScheduleSpec, seed: int, n: int):
    assert spec.bounds is not None
    low, high = float(spec.bounds[2]), float(spec.bounds[3])
    schedule = compile_spec(spec)
    key = key_of(seed)
    assert schedule.certificate.bounds == (low, high)
    assert low <= schedule.certificate.minimum and schedule.certificate.maximum <= high
    values = np.asarray(schedule.alpha(jnp.asarray(float32_grid(2001)), key), np.float64)
    phases = np.asarray(schedule.phase_alphas(n, key), np.float64)
    for sample in (values, phases):
        slack = ATOL + RTOL * np.abs(sample)
        assert np.all(sample >= low - slack) and np.all(sample <= high + slack), (sample.min(), sample.max())


@settings(max_examples=10, **COMMON)
@given(valid_schedules(kinds=MONOTONE_KINDS), seeds)
def test_declared_and_certified_monotone_segments_are_monotone(spec: ScheduleSpec, seed: int):
    schedule = compile_spec(spec)
    key = key_of(seed)
    for j, segment in enumerate(spec.segments):
        if segment.declared is None:
            continue
        values = np.asarray(schedule.alpha(jnp.asarray(inside(segment.start, segment.end, 200)), key))
        assert monotone_on(values, segment.declared), (j, segment.shape, segment.declared, values)
    for piece in schedule.certificate.pieces:
        if piece.monotone in ("increasing", "decreasing"):
            points = inside(Fraction(piece.start), Fraction(piece.end), 200)
            values = np.asarray(schedule.alpha(jnp.asarray(points), key))
            assert monotone_on(values, piece.monotone), piece
            assert (
                piece.monotone in spec.segments[piece.segment - 1].allowed
                or spec.segments[piece.segment - 1].kind == "bell"
            ), piece


# ----------------------------------------------------------------------------- discretisation


@settings(max_examples=10, **COMMON)
@given(valid_schedules(kinds=FAST_KINDS, declare=False), seeds, phase_counts)
def test_phase_alphas_sample_alpha_at_phase_starts(spec: ScheduleSpec, seed: int, n: int):
    schedule = compile_spec(spec)
    key = key_of(seed)
    phases = np.asarray(schedule.phase_alphas(n, key))
    assert phases.shape == (n,)
    sampled = np.asarray(schedule.alpha(jnp.arange(n) / n, key))
    assert close(phases, sampled.astype(np.float64)), [
        (k, float(phases[k]), float(sampled[k])) for k in range(n) if not close(phases[k], float(sampled[k]))
    ][:5]
    draws = draws_of(schedule, key)
    truth = np.asarray([spec.alpha(Fraction(k, n), draws) for k in range(n)])
    assert close(phases, truth), [(k, float(phases[k]), truth[k]) for k in range(n) if not close(phases[k], truth[k])][
        :5
    ]
    assert np.array_equal(np.asarray(schedule.phase_alphas(n, None)), np.asarray(schedule.phase_alphas(n, key_of(0))))


@settings(max_examples=8, **COMMON)
@given(valid_schedules(kinds=FAST_KINDS, declare=False), seeds, phase_counts, st.data())
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
        assert float(jitted(jnp.int32(k))) == float(phases[k]), k
    assert len(traces) == 1, "phase_alpha was traced more than once for different k"
    assert isinstance(traces[0], jax.core.Tracer)
    assert np.array_equal(np.asarray(jax.vmap(jitted)(jnp.arange(n, dtype=jnp.int32))), phases)


# ----------------------------------------------------------------------------- random segments


@settings(max_examples=10, **COMMON)
@given(valid_schedules(kinds=RANDOM_HEAVY, declare=False), seeds, seeds, phase_counts)
def test_random_segments_are_a_function_of_the_key(spec: ScheduleSpec, seed: int, other: int, n: int):
    schedule = compile_spec(spec)
    same = [np.asarray(schedule.phase_alphas(n, key_of(seed))) for _ in range(2)]
    assert np.array_equal(same[0], same[1])
    first, again = draws_of(schedule, key_of(seed)), draws_of(schedule, key_of(seed))
    for a, b in zip(first, again):
        assert (a is None and b is None) or np.array_equal(a, b)
    grid = jnp.asarray(float32_grid(301))
    assert np.array_equal(
        np.asarray(schedule.alpha(grid, key_of(seed))), np.asarray(schedule.alpha(grid, key_of(seed)))
    )
    if other != seed:
        different = draws_of(schedule, key_of(other))
        for segment, a, b in zip(spec.segments, first, different):
            assert (segment.random is None) == (a is None) == (b is None)
            if segment.random is not None:
                assert a.shape == b.shape == (segment.random.count,)
                # independent uniform float32 draws coincide with probability ~2**-23 per value
                assert not np.array_equal(a, b) or (segment.random.count == 1 and a[0] != b[0])


@settings(max_examples=10, **COMMON)
@given(valid_schedules(kinds=RANDOM_HEAVY, declare=False), seeds, phase_counts)
def test_random_values_lie_in_their_range(spec: ScheduleSpec, seed: int, n: int):
    schedule = compile_spec(spec)
    key = key_of(seed)
    points = float32_grid(1001)
    values = np.asarray(schedule.alpha(jnp.asarray(points), key), np.float64)
    phases = np.asarray(schedule.phase_alphas(n, key), np.float64)
    for j, segment in enumerate(spec.segments):
        if segment.random is None:
            continue
        low, high = float(segment.random.low), float(segment.random.high)
        draws = np.asarray(schedule.draws(key)[j])
        assert np.all((draws >= 0) & (draws < 1))
        here = [spec.segment_at(Fraction(float(x))) == j for x in points]
        mine = [spec.segment_at(Fraction(k, n)) == j for k in range(n)]
        for sample in (values[here], phases[mine]):
            slack = 1e-6 * max(1.0, high)
            assert np.all(sample >= low - slack) and np.all(sample <= high + slack), (low, high, sample)


@settings(max_examples=10, **COMMON)
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
    # every phase shows the draw of its bin, and a new bin means a new value
    for k, b in zip(ks, bins):
        assert close(phases[k], float(r.low) + float(r.high - r.low) * float(draws[b])), (k, b)
    if r.low < r.high:
        for (k0, b0), (k1, b1) in zip(zip(ks, bins), zip(ks[1:], bins[1:])):
            assert (phases[k0] == phases[k1]) == (b0 == b1), (k0, k1, b0, b1)
        assert len(set(phases[ks].tolist())) == len(set(bins)) == r.count


@settings(max_examples=6, **COMMON)
@given(
    st.sampled_from(("", " every 1%", " every 0.01", " every 1/100")),
    st.integers(10, 200),
    st.integers(0, 100),
    seeds,
)
def test_a_one_percent_random_segment_over_90_percent_has_90_values_at_100_phases(every, lo, extra, seed):
    low, high = lo / 100, (lo + 1 + extra) / 100
    schedule = smol_dsl.parse(f"0% .. 90%: random {low} .. {high}{every}\n90% .. 100%: tail\n")
    phases = np.asarray(schedule.phase_alphas(100, key_of(seed)))
    body = phases[:90]
    assert len(set(body.tolist())) == 90
    assert np.all(body[1:] != body[:-1])  # the draw changes at every phase
    assert np.all((body >= np.float32(low)) & (body <= np.float32(high)))
    assert np.all(phases[90:] == 1.0)


# ----------------------------------------------------------------------------- invalid schedules


@settings(max_examples=40, **COMMON)
@given(invalid_schedules(kinds=FAST_KINDS))
def test_invalid_schedules_raise_one_located_schedule_error(case):
    try:
        smol_dsl.parse(case.text, path="case.sched")
    except smol_dsl.ScheduleError as error:
        caught = error
    except Exception as error:  # anything else is a bug
        pytest.fail(f"{case.rule}: {type(error).__name__}: {error}\n{case.text}")
    else:
        pytest.fail(f"{case.rule}: accepted\n{case.text}")
    assert caught.line is not None and caught.line >= 1, case.rule
    assert caught.column is not None and caught.column >= 1, case.rule
    assert caught.hint, case.rule
    shown = str(caught)
    assert shown.startswith(f"case.sched:{caught.line}:{caught.column}: error: "), shown
    assert "hint: " in shown
    if case.line is not None:
        assert caught.line == case.line, (case.rule, str(caught), case.text)
    if case.message is not None:
        assert case.message in caught.message, (case.rule, caught.message)
