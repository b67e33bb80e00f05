"""`Curve`: one channel's verified schedule, evaluated in JAX (what `Schedule` has per channel).

A curve is a channel's segments in exact sympy, its certificate, and the per-segment tables
from which its value is gathered: jittable and vmappable functions of progress t or of the
phase index, in memory linear in the number of segments.
"""

from __future__ import annotations

import bisect
import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from typing import TYPE_CHECKING, Any

import numpy as np

from smol_dsl.errors import ScheduleError
from smol_dsl.language.channels import GEAR, Channel
from smol_dsl.language.shapes import Drawn, Formula, Line
from smol_dsl.language.symbolic import SymbolicCurve, SymbolicSegment, percent
from smol_dsl.language.verify import tail_start

# JAX is imported inside the functions that evaluate: parsing and checking a schedule never load it.
if TYPE_CHECKING:
    import jax
    import sympy as sp

    from smol_dsl.language.certificates import Certificate

RANDOM_BIN_TOLERANCE = 1e-4
"""Float t within this many bins below a bin edge counts as on the edge (absorbs rounding)."""


def fraction(value: sp.Rational) -> Fraction:
    """An exact sympy rational as a Fraction."""
    return Fraction(int(value.p), int(value.q))


def default_key(key: jax.Array | None) -> jax.Array:
    """`key`, or the fixed default key `jax.random.key(0)` when None; TypeError for what is not
    one JAX random key (`check_key`)."""
    import jax

    return jax.random.key(0) if key is None else check_key(key)


def check_key(key: jax.Array | None, *, none_allowed: bool = True) -> jax.Array | None:
    """`key` (None too, where `none_allowed`), or a TypeError for what is not one JAX random
    key: a typed key (`jax.random.key(seed)`) or a raw one (`jax.random.PRNGKey(seed)`, uint32[2])."""
    import jax
    import jax.numpy as jnp

    if key is None and none_allowed:
        return None
    dtype, shape = getattr(key, "dtype", None), getattr(key, "shape", None)
    if dtype is not None and jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key) and shape == ():
        return key
    if dtype == jnp.uint32 and shape == (2,):  # a raw key, as jax.random.PRNGKey gives
        return key
    default = " (None: that default)" if none_allowed else ""
    raise TypeError(f"key is one JAX random key, e.g. jax.random.key(0){default}, not {_shown(key)}")


def _shown(value: Any) -> str:
    """A value for a message: an array by its dtype and shape, anything else by its repr."""
    if hasattr(value, "dtype") and hasattr(value, "shape"):
        return f"an array of {value.dtype}{list(value.shape)}"
    return repr(value)


def check_phases(num_phases: int) -> None:
    """Refuse a number of phases that is not a positive int."""
    if not isinstance(num_phases, (int, np.integer)) or isinstance(num_phases, bool) or num_phases < 1:
        raise ValueError(f"num_phases must be a positive int, not {num_phases!r}")


@dataclass(frozen=True)
class _Tables:
    """Per-segment numbers from which the value is gathered, so that evaluating a curve of any
    number of segments holds O(len(t)) values, not one array per segment.

    Each segment's shape says how (`Shape.evaluation`): a `Line` is `offset + scale * u` with
    u = (t - start) / (end - start) in [0, 1] (constant, linear, tail, and every segment of the
    tail), a `Drawn` one `offset + scale * draw[first_draw + bin]` (random), and a
    `Formula` (expr, bell) is evaluated one by one and selected with `where`.
    """

    starts: np.ndarray  # float64, segment starts
    inverse_lengths: np.ndarray  # 1 / (end - start)
    offsets: np.ndarray
    scales: np.ndarray
    is_random: np.ndarray  # bool: the value is offset + scale * draw
    first_draws: np.ndarray  # int32: where a segment's draws start in the flat draws
    draw_counts: np.ndarray  # int32: its number of draws (1 elsewhere)
    random_every: np.ndarray  # its draws' `every` (1 elsewhere)
    formulas: tuple[tuple[int, Callable[..., Any]], ...]  # (index, JAX function) of Formula segments


class Curve:
    """One channel's verified schedule over training progress t in [0, 1].

    `Schedule.curve(channel)` gives one. Its value is a factor on the standard body, 1 being
    the standard body; `value` evaluates it, jittably (and `phase_value(s)` per phase):

    >>> import smol_dsl
    >>> mass = smol_dsl.load("growth").curve("mass")
    >>> round(float(mass.value(0.0)), 6), float(mass.value(0.95)), mass.final
    (0.3, 1.0, 1.0)
    """

    def __init__(self, symbolic: SymbolicCurve, certificate: Certificate, source: str, path: str | None):
        self._symbolic = symbolic
        self.channel: Channel = symbolic.channel
        self.certificate: Certificate = certificate
        self.source: str = source
        self.path: str | None = path
        self.segments: tuple[SymbolicSegment, ...] = symbolic.segments
        self.place = symbolic.place
        """Where its `channel` line names it and its targets (None: the implicit gear channel)."""
        self.final: float = float(symbolic.final)
        """The channel's value over its tail: its body at the end of the run (1 unless declared)."""
        self.tail_start: Fraction = fraction(tail_start(symbolic))
        """Where the curve becomes its final value for good."""
        self._table_cache: _Tables | None = None
        self._phase_table_cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._phase_values_compiled: dict[int, Callable[..., Any]] = {}

    @property
    def name(self) -> str:
        """The channel's name: `gear`, `mass`, `gear[left_leg]`."""
        return self.channel.name

    @property
    def symbolic(self) -> sp.Piecewise:
        """The curve as one exact sympy Piecewise in `smol_dsl.language.symbolic.T`."""
        return self._symbolic.piecewise

    def channel_key(self, key: jax.Array | None) -> jax.Array:
        """The key this curve's random segments draw from: `key` itself for plain gear (so that a
        plain-gear file draws from the run's key, with or without other channels), else
        `fold_in(key, crc32(name))`, whatever the order in which channels are declared."""
        import jax

        key = default_key(key)
        if self.channel == GEAR:
            return key
        return jax.random.fold_in(key, zlib.crc32(self.channel.name.encode()))

    # ------------------------------------------------------------------ JAX
    def value(self, t: jax.typing.ArrayLike, key: jax.Array | None = None) -> jax.Array:
        """The value at progress `t` (scalar or array, clipped to [0, 1]); jit- and vmap-able.

        Random segments draw from `key` (a fixed default key when None): the same key
        always gives the same schedule. Every channel but plain gear draws from
        `fold_in(key, crc32(name))` (`channel_key`), so channels draw independently.
        """
        import jax.numpy as jnp

        key = check_key(key)  # also where no segment draws: a wrong argument is wrong regardless
        t = jnp.clip(jnp.asarray(t, dtype=jnp.result_type(float)), 0.0, 1.0)
        tables = self._tables()
        index = jnp.searchsorted(jnp.asarray(tables.starts[1:], dtype=t.dtype), t, side="right")
        return self._select(t, index, self._bin_of(t, index), key)

    def phase_value(self, k: jax.typing.ArrayLike, num_phases: int, key: jax.Array | None = None) -> jax.Array:
        """The value during phase `k` of `num_phases`: the curve at the phase's start, t = k / N.

        `k` may be traced (one compilation serves every phase); `num_phases` is static.
        Which segment and which random draw a phase gets is decided in exact rational
        arithmetic, so phase 90 of 100 is exactly at the 90% boundary.
        """
        import jax.numpy as jnp

        key = check_key(key)
        segment_of, bin_of = self._phase_tables(num_phases)
        k = jnp.clip(jnp.asarray(k, dtype=jnp.int32), 0, num_phases - 1)
        t = k.astype(jnp.result_type(float)) / num_phases
        return self._select(t, jnp.asarray(segment_of)[k], jnp.asarray(bin_of)[k], key)

    def phase_values(self, num_phases: int, key: jax.Array | None = None) -> jax.Array:
        """The value for every phase of `num_phases`, shape (num_phases,)."""
        import jax

        check_phases(num_phases)
        if num_phases not in self._phase_values_compiled:
            import jax.numpy as jnp

            self._phase_values_compiled[num_phases] = jax.jit(
                lambda key: self.phase_value(jnp.arange(num_phases), num_phases, key)
            )
        return self._phase_values_compiled[num_phases](default_key(key))

    def checked_phase_values(self, num_phases: int, key: jax.Array | None = None) -> np.ndarray:
        """`phase_values` on the host, refused with a ScheduleError if any is not finite and positive.

        The certificate proves this never happens; runners call it before training anyway, so
        that a defect can never waste a run.
        """
        values = np.asarray(self.phase_values(num_phases, key))
        self.check_phase_values(values, num_phases)
        return values

    def check_phase_values(self, values: np.ndarray, num_phases: int) -> None:
        """Refuse this curve's phase values (host arrays) if any is not finite and positive."""
        bad = np.flatnonzero(~(np.isfinite(values) & (values > 0)))
        if bad.size:
            k = int(bad[0])
            segment = self.segments[int(self._phase_tables(num_phases)[0][k])]
            raise ScheduleError(
                f"{self.channel.quantity} of phase {k} of {num_phases} (t = {percent(Fraction(k, num_phases))}, "
                f"segment {segment.index + 1}) is {values[k]} in float32; {bad.size} phase(s) are not finite "
                "and positive",
                span=segment.span,
                hint="this is a bug in smol-dsl's verification; please report the schedule",
                source=self.source,
                path=self.path,
            )

    def as_optax(
        self, total_steps: int, *, num_phases: int | None = None, key: jax.Array | None = None
    ) -> Callable[[jax.typing.ArrayLike], jax.Array]:
        """An optax-style schedule: a function of the step count returning the value.

        With `num_phases`, the value is held constant within each of that many equal phases
        (as the runner does); otherwise it follows the smooth curve.

        >>> import smol_dsl
        >>> schedule = smol_dsl.load("smol").curve("gear").as_optax(1000, num_phases=100)
        >>> float(schedule(950))
        1.0
        """
        if total_steps <= 0:
            raise ValueError(f"total_steps must be positive, not {total_steps}")
        if num_phases is not None:
            check_phases(num_phases)
            # phase k starts at step ceil(k * total / N), computed exactly here so that a
            # traced int32 count never overflows in count * N
            first_steps = np.asarray([-(-k * total_steps // num_phases) for k in range(1, num_phases)], dtype=np.int64)
            if total_steps > 2**31 - 1:
                raise ValueError(f"total_steps must be at most 2**31 - 1 for int32 step counts, not {total_steps}")

        def schedule(count: jax.typing.ArrayLike) -> jax.Array:
            import jax.numpy as jnp

            if num_phases is None:
                return self.value(jnp.asarray(count) / total_steps, key)
            boundaries = jnp.asarray(first_steps, dtype=jnp.int32)
            phase = jnp.searchsorted(boundaries, jnp.asarray(count, dtype=jnp.int32), side="right")
            return self.phase_value(phase, num_phases, key)

        return schedule

    def draws(self, key: jax.Array | None = None) -> list[jax.Array | None]:
        """The uniform [0, 1) draws of each random segment under `key` (None elsewhere)."""
        draws: list[jax.Array | None] = [None] * len(self.segments)
        for indices, drawn in self._drawn_groups(key):
            for row, j in enumerate(indices):
                draws[j] = drawn[row]
        return draws

    def _draw_groups(self) -> dict[int, list[int]]:
        """The random segments' indices by their number of draws, in order of first appearance."""
        by_count: dict[int, list[int]] = {}
        for segment in self.segments:
            if segment.draws is not None:
                by_count.setdefault(segment.draws.count, []).append(segment.index)
        return by_count

    def _drawn_groups(self, key: jax.Array | None) -> list[tuple[list[int], jax.Array]]:
        """Each group of `_draw_groups`: its segments' indices and their draws, one row per
        segment."""
        import jax

        key = self.channel_key(key)
        # Segment j draws uniform(fold_in(key, j), (count,)). Segments with the same count are
        # drawn together under vmap (the same numbers, one operation per distinct count), so
        # that a schedule of many random segments compiles quickly.
        groups = []
        for count, indices in self._draw_groups().items():
            keys = jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, jax.numpy.asarray(indices))
            groups.append((indices, jax.vmap(lambda k, count=count: jax.random.uniform(k, (count,)))(keys)))
        return groups

    def _flat_draws(self, key: Any) -> jax.Array:
        """Every random segment's draws, one after the other in segment order: `draws`
        concatenated, bit for bit, gathered from the groups' rows in one operation (not one
        slice per segment, which makes a program of many random segments slow to compile)."""
        import jax.numpy as jnp

        flat = jnp.concatenate([drawn.reshape(-1) for _, drawn in self._drawn_groups(key)])
        order = self._flat_draw_order()
        return flat if order is None else flat[order]

    def _flat_draw_order(self) -> np.ndarray | None:
        """Where each of `_flat_draws` lies in the groups' flattened rows (None: in place)."""
        position, where = 0, {}
        for count, indices in self._draw_groups().items():
            for j in indices:
                where[j] = np.arange(position, position + count)
                position += count
        order = np.concatenate([where[j] for j in sorted(where)]).astype(np.int32)
        return None if np.array_equal(order, np.arange(order.size)) else order

    # ------------------------------------------------------------------ internals
    def _bin_of(self, t: jax.Array, index: jax.Array) -> jax.Array:
        """The random bin of t within its segment (0 outside random segments)."""
        import jax.numpy as jnp

        tables = self._tables()
        if not tables.is_random.any():
            return jnp.zeros(t.shape, dtype=jnp.int32)
        start = jnp.asarray(tables.starts, dtype=t.dtype)[index]
        every = jnp.asarray(tables.random_every, dtype=t.dtype)[index]
        bins = jnp.floor((t - start) / every + RANDOM_BIN_TOLERANCE).astype(jnp.int32)
        return jnp.clip(bins, 0, jnp.asarray(tables.draw_counts)[index] - 1)

    def _phase_tables(self, num_phases: int) -> tuple[np.ndarray, np.ndarray]:
        """For each phase k: its segment and its random bin, in exact rational arithmetic."""
        check_phases(num_phases)
        if num_phases not in self._phase_table_cache:
            starts = [fraction(s.start) for s in self.segments]
            segment_of = np.zeros(num_phases, dtype=np.int32)
            bin_of = np.zeros(num_phases, dtype=np.int32)
            for k in range(num_phases):
                t = Fraction(k, num_phases)
                j = bisect.bisect_right(starts, t) - 1
                segment_of[k] = j
                draws = self.segments[j].draws
                if draws is not None:
                    bin_of[k] = min(math.floor((t - starts[j]) / fraction(draws.every)), draws.count - 1)
            self._phase_table_cache[num_phases] = (segment_of, bin_of)
        return self._phase_table_cache[num_phases]

    def _select(self, t: jax.Array, index: jax.Array, bins: jax.Array, key: Any) -> jax.Array:
        """The value at t, given t's segment `index` and random bin: gathered from the tables, then
        each formula segment evaluated and put in place with `where` (O(len(t)) memory)."""
        import jax.numpy as jnp

        tables = self._tables()

        def table(values: np.ndarray) -> jax.Array:
            return jnp.asarray(values, dtype=t.dtype)[index]

        start = table(tables.starts)
        fraction = jnp.clip((t - start) * table(tables.inverse_lengths), 0.0, 1.0)
        if tables.is_random.any():
            draws = self._flat_draws(key).astype(t.dtype)
            drawn = draws[jnp.asarray(tables.first_draws)[index] + bins]
            fraction = jnp.where(jnp.asarray(tables.is_random)[index], drawn, fraction)
        value = table(tables.offsets) + table(tables.scales) * fraction
        for j, function in tables.formulas:
            segment = self.segments[j]
            inside = jnp.clip(t, float(segment.start), float(segment.end))
            value = jnp.where(index == j, function(inside).astype(t.dtype), value)
        return value

    def _tables(self) -> _Tables:
        if self._table_cache is None:
            count = len(self.segments)
            offsets, scales = np.zeros(count), np.zeros(count)
            first_draws, draw_counts = np.zeros(count, dtype=np.int32), np.ones(count, dtype=np.int32)
            random_every, is_random = np.ones(count), np.zeros(count, dtype=bool)
            formulas = []
            drawn = 0
            for j, segment in enumerate(self.segments):
                # proven identically the final value from the tail's start (say sin(t)**2 + cos(t)**2):
                # exactly that value in floats too
                in_tail = fraction(segment.start) >= self.tail_start
                evaluation = Line(self.final) if in_tail else segment.shape.evaluation(segment)
                if isinstance(evaluation, Line):
                    offsets[j], scales[j] = evaluation.offset, evaluation.scale
                elif isinstance(evaluation, Drawn):
                    assert segment.draws is not None, f"a Drawn segment without draws: {segment.kind}"
                    offsets[j], scales[j] = evaluation.offset, evaluation.scale
                    is_random[j] = True
                    first_draws[j], draw_counts[j] = drawn, segment.draws.count
                    random_every[j] = float(segment.draws.every)
                else:
                    assert isinstance(evaluation, Formula)
                    formulas.append((j, evaluation.function))
                if segment.draws is not None:
                    drawn += segment.draws.count
            starts = np.array([float(s.start) for s in self.segments])
            ends = np.array([float(s.end) for s in self.segments])
            self._table_cache = _Tables(
                starts=starts,
                inverse_lengths=1.0 / (ends - starts),
                offsets=offsets,
                scales=scales,
                is_random=is_random,
                first_draws=first_draws,
                draw_counts=draw_counts,
                random_every=random_every,
                formulas=tuple(formulas),
            )
        return self._table_cache

    def __repr__(self) -> str:
        c = self.certificate
        return (
            f"Curve({self.name}, segments={len(self.segments)}, in [{c.minimum:.4g}, {c.maximum:.4g}], "
            f"final {self.final:g} from {percent(self.tail_start)})"
        )
