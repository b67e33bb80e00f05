"""`Schedule`: a verified, compiled `.sched` file, and `parse` / `load` to get one."""

from __future__ import annotations

import bisect
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import sympy as sp

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.language.compiler import compile_program
from smol_dsl.language.library import library_dir, library_names
from smol_dsl.language.shapes import Drawn, Formula, Line
from smol_dsl.language.symbolic import SymbolicProgram, SymbolicSegment, percent
from smol_dsl.language.syntax import parse_program
from smol_dsl.language.verify import Certificate, tail_start, verify

if TYPE_CHECKING:
    import jax

RANDOM_BIN_TOLERANCE = 1e-4
"""Float t within this many bins below a bin edge counts as on the edge (absorbs rounding)."""


def _fraction(value: sp.Rational) -> Fraction:
    return Fraction(int(value.p), int(value.q))


@dataclass(frozen=True)
class _Tables:
    """Per-segment numbers from which alpha is gathered, so that evaluating a schedule of any
    number of segments holds O(len(t)) values, not one array per segment.

    Each segment's shape says how (`Shape.evaluation`): a `Line` is `offset + scale * u` with
    u = (t - start) / (end - start) in [0, 1] (constant, linear, tail, and every segment of the
    alpha == 1 tail), a `Drawn` one `offset + scale * draw[first_draw + bin]` (random), and a
    `Formula` (expr, bell) is evaluated one by one and selected with `where`.
    """

    starts: np.ndarray  # float64, segment starts
    inverse_lengths: np.ndarray  # 1 / (end - start)
    offsets: np.ndarray
    scales: np.ndarray
    is_random: np.ndarray  # bool: alpha is offset + scale * draw
    first_draws: np.ndarray  # int32: where a segment's draws start in the flat draws
    draw_counts: np.ndarray  # int32: its number of draws (1 elsewhere)
    random_every: np.ndarray  # its draws' `every` (1 elsewhere)
    formulas: tuple[tuple[int, Callable[..., Any]], ...]  # (index, JAX function) of Formula segments


class Schedule:
    """A verified schedule alpha(t) over training progress t in [0, 1].

    Get one with `smol_dsl.load("human")` or `smol_dsl.parse(text)`. Everything that
    evaluates alpha is pure and jittable:

    >>> import jax, smol_dsl
    >>> smol = smol_dsl.load("smol")
    >>> float(smol.alpha(0.0)), float(smol.alpha(0.95))
    (1.5, 1.0)
    >>> smol.phase_alphas(100, jax.random.key(0)).shape
    (100,)
    """

    def __init__(self, program: SymbolicProgram, certificate: Certificate, source: str, path: str | None):
        self._program = program
        self.certificate: Certificate = certificate
        self.source: str = source
        self.path: str | None = path
        stem = Path(path).stem if path else None
        self.name: str = program.name or stem or "schedule"
        self.description: str = program.description or ""
        self.extinction: float = float(program.extinction)
        self.segments: tuple[SymbolicSegment, ...] = program.segments
        self.tail_start: Fraction = _fraction(tail_start(self.segments))
        self._table_cache: _Tables | None = None
        self._phase_table_cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._phase_alphas_compiled: dict[int, Callable[..., Any]] = {}

    # ------------------------------------------------------------------ symbolic
    @property
    def symbolic(self) -> sp.Piecewise:
        """alpha(t) as one exact sympy Piecewise in `smol_dsl.language.symbolic.T`."""
        return self._program.piecewise

    def tail_phases(self, num_phases: int) -> int:
        """How many of `num_phases` equal phases lie wholly inside the alpha == 1 tail."""
        _check_phases(num_phases)
        return num_phases - math.ceil(self.tail_start * num_phases)

    # ------------------------------------------------------------------ JAX
    def alpha(self, t: jax.typing.ArrayLike, key: jax.Array | None = None) -> jax.Array:
        """alpha at progress `t` (scalar or array, clipped to [0, 1]); jit- and vmap-able.

        Random segments draw from `key` (a fixed default key when None): the same key
        always gives the same schedule.
        """
        import jax.numpy as jnp

        t = jnp.clip(jnp.asarray(t, dtype=jnp.result_type(float)), 0.0, 1.0)
        tables = self._tables()
        index = jnp.searchsorted(jnp.asarray(tables.starts[1:], dtype=t.dtype), t, side="right")
        return self._select(t, index, self._bin_of(t, index), key)

    def phase_alpha(self, k: jax.typing.ArrayLike, num_phases: int, key: jax.Array | None = None) -> jax.Array:
        """alpha during phase `k` of `num_phases`: the curve at the phase's start, t = k / N.

        `k` may be traced (one compilation serves every phase); `num_phases` is static.
        Which segment and which random draw a phase gets is decided in exact rational
        arithmetic, so phase 90 of 100 is exactly at the 90% boundary.
        """
        import jax.numpy as jnp

        segment_of, bin_of = self._phase_tables(num_phases)
        k = jnp.clip(jnp.asarray(k, dtype=jnp.int32), 0, num_phases - 1)
        t = k.astype(jnp.result_type(float)) / num_phases
        return self._select(t, jnp.asarray(segment_of)[k], jnp.asarray(bin_of)[k], key)

    def phase_alphas(self, num_phases: int, key: jax.Array | None = None) -> jax.Array:
        """alpha for every phase of `num_phases`, shape (num_phases,)."""
        import jax

        _check_phases(num_phases)
        if num_phases not in self._phase_alphas_compiled:
            import jax.numpy as jnp

            self._phase_alphas_compiled[num_phases] = jax.jit(
                lambda key: self.phase_alpha(jnp.arange(num_phases), num_phases, key)
            )
        return self._phase_alphas_compiled[num_phases](_default_key(key))

    def checked_phase_alphas(self, num_phases: int, key: jax.Array | None = None) -> np.ndarray:
        """`phase_alphas` on the host, refused with a ScheduleError if any is not finite and positive.

        The certificate proves this never happens; runners call it before training anyway, so
        that a defect can never waste a run.
        """
        alphas = np.asarray(self.phase_alphas(num_phases, key))
        bad = np.flatnonzero(~(np.isfinite(alphas) & (alphas > 0)))
        if bad.size:
            k = int(bad[0])
            segment = self.segments[int(self._phase_tables(num_phases)[0][k])]
            raise ScheduleError(
                f"alpha of phase {k} of {num_phases} (t = {percent(Fraction(k, num_phases))}, segment "
                f"{segment.index + 1}) is {alphas[k]} in float32; {bad.size} phase(s) are not finite and positive",
                span=segment.span,
                hint="this is a bug in smol-dsl's verification; please report the schedule",
                source=self.source,
                path=self.path,
            )
        return alphas

    def as_optax(
        self, total_steps: int, *, num_phases: int | None = None, key: jax.Array | None = None
    ) -> Callable[[jax.typing.ArrayLike], jax.Array]:
        """An optax-style schedule: a function of the step count returning alpha.

        With `num_phases`, alpha is held constant within each of that many equal phases
        (as the runner does); otherwise it follows the smooth curve.

        >>> schedule = smol_dsl.load("smol").as_optax(1000, num_phases=100)
        >>> float(schedule(950))
        1.0
        """
        if total_steps <= 0:
            raise ValueError(f"total_steps must be positive, not {total_steps}")
        if num_phases is not None:
            _check_phases(num_phases)
            # phase k starts at step ceil(k * total / N), computed exactly here so that a
            # traced int32 count never overflows in count * N
            first_steps = np.asarray([-(-k * total_steps // num_phases) for k in range(1, num_phases)], dtype=np.int64)
            if total_steps > 2**31 - 1:
                raise ValueError(f"total_steps must be at most 2**31 - 1 for int32 step counts, not {total_steps}")

        def schedule(count: jax.typing.ArrayLike) -> jax.Array:
            import jax.numpy as jnp

            if num_phases is None:
                return self.alpha(jnp.asarray(count) / total_steps, key)
            boundaries = jnp.asarray(first_steps, dtype=jnp.int32)
            phase = jnp.searchsorted(boundaries, jnp.asarray(count, dtype=jnp.int32), side="right")
            return self.phase_alpha(phase, num_phases, key)

        return schedule

    def draws(self, key: jax.Array | None = None) -> list[jax.Array | None]:
        """The uniform [0, 1) draws of each random segment under `key` (None elsewhere)."""
        import jax

        key = _default_key(key)
        # Segment j draws uniform(fold_in(key, j), (count,)). Segments with the same count are
        # drawn together under vmap (the same numbers, one operation per distinct count), so
        # that a schedule of many random segments compiles quickly.
        by_count: dict[int, list[int]] = {}
        for segment in self.segments:
            if segment.draws is not None:
                by_count.setdefault(segment.draws.count, []).append(segment.index)
        draws: list[jax.Array | None] = [None] * len(self.segments)
        for count, indices in by_count.items():
            keys = jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, jax.numpy.asarray(indices))
            drawn = jax.vmap(lambda k, count=count: jax.random.uniform(k, (count,)))(keys)
            for row, j in enumerate(indices):
                draws[j] = drawn[row]
        return draws

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
        _check_phases(num_phases)
        if num_phases not in self._phase_table_cache:
            starts = [_fraction(s.start) for s in self.segments]
            segment_of = np.zeros(num_phases, dtype=np.int32)
            bin_of = np.zeros(num_phases, dtype=np.int32)
            for k in range(num_phases):
                t = Fraction(k, num_phases)
                j = bisect.bisect_right(starts, t) - 1
                segment_of[k] = j
                draws = self.segments[j].draws
                if draws is not None:
                    bin_of[k] = min(math.floor((t - starts[j]) / _fraction(draws.every)), draws.count - 1)
            self._phase_table_cache[num_phases] = (segment_of, bin_of)
        return self._phase_table_cache[num_phases]

    def _select(self, t: jax.Array, index: jax.Array, bins: jax.Array, key: Any) -> jax.Array:
        """alpha at t, given t's segment `index` and random bin: gathered from the tables, then
        each formula segment evaluated and put in place with `where` (O(len(t)) memory)."""
        import jax.numpy as jnp

        tables = self._tables()

        def table(values: np.ndarray) -> jax.Array:
            return jnp.asarray(values, dtype=t.dtype)[index]

        start = table(tables.starts)
        fraction = jnp.clip((t - start) * table(tables.inverse_lengths), 0.0, 1.0)
        if tables.is_random.any():
            draws = jnp.concatenate([d for d in self.draws(key) if d is not None]).astype(t.dtype)
            drawn = draws[jnp.asarray(tables.first_draws)[index] + bins]
            fraction = jnp.where(jnp.asarray(tables.is_random)[index], drawn, fraction)
        alpha = table(tables.offsets) + table(tables.scales) * fraction
        for j, function in tables.formulas:
            segment = self.segments[j]
            inside = jnp.clip(t, float(segment.start), float(segment.end))
            alpha = jnp.where(index == j, function(inside).astype(t.dtype), alpha)
        return alpha

    def _tables(self) -> _Tables:
        if self._table_cache is None:
            count = len(self.segments)
            offsets, scales = np.zeros(count), np.zeros(count)
            first_draws, draw_counts = np.zeros(count, dtype=np.int32), np.ones(count, dtype=np.int32)
            random_every, is_random = np.ones(count), np.zeros(count, dtype=bool)
            formulas = []
            drawn = 0
            for j, segment in enumerate(self.segments):
                # proven identically 1 from the tail's start (say sin(t)**2 + cos(t)**2): exactly 1.0 in floats too
                at_one = _fraction(segment.start) >= self.tail_start
                evaluation = Line(1.0) if at_one else segment.shape.evaluation(segment)
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
            f"Schedule({self.name!r}, segments={len(self.segments)}, "
            f"alpha in [{c.minimum:.4g}, {c.maximum:.4g}], tail from {percent(self.tail_start)}, "
            f"extinction={self.extinction:g})"
        )


def _default_key(key: jax.Array | None) -> jax.Array:
    import jax

    return jax.random.key(0) if key is None else key


def _check_phases(num_phases: int) -> None:
    if not isinstance(num_phases, (int, np.integer)) or isinstance(num_phases, bool) or num_phases < 1:
        raise ValueError(f"num_phases must be a positive int, not {num_phases!r}")


def parse(text: str, *, path: str | os.PathLike[str] | None = None) -> Schedule:
    """Parse, compile and verify `.sched` text; raise `ScheduleError` if anything is wrong."""
    shown = str(path) if path is not None else None
    try:
        program = parse_program(text)
        symbolic = compile_program(program)
        certificate = verify(symbolic)
    except ScheduleError as error:
        raise error.located(text, shown) from None
    except RecursionError:
        raise ScheduleError(
            "expression nested too deeply",
            span=Span(1, 1),
            hint="split it with `let` constants",
            source=text,
            path=shown,
        ) from None
    return Schedule(symbolic, certificate, text, shown)


def read_text(path: Path) -> str:
    """Read a `.sched` file as UTF-8, with a located error for bytes that are not text."""
    data = path.read_bytes()
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        before = data[: error.start]
        line = before.count(b"\n") + 1
        column = len(before) - (before.rfind(b"\n") + 1) + 1
        raise ScheduleError(
            f"byte 0x{data[error.start]:02x} is not UTF-8 text",
            span=Span(line, column),
            hint="a .sched file is plain UTF-8 text; is this a binary file?",
            path=str(path),
        ) from None


def resolve(path_or_name: str | os.PathLike[str]) -> Path:
    """The file a path or a bundled name refers to: a file here first, then the library."""
    path = Path(path_or_name)
    if path.is_file():
        return path
    if path.exists():
        raise ScheduleError(f"{path} is not a file", path=str(path), hint="give the path of a .sched file")
    text = str(path_or_name)
    if os.sep not in text and "/" not in text:
        stem = text[: -len(".sched")] if text.endswith(".sched") else text
        bundled = library_dir() / f"{stem}.sched"
        if bundled.is_file():
            return bundled
    raise ScheduleError(
        "no such file",
        path=text,
        hint="bundled schedules: " + ", ".join(library_names()),
    )


def load(path_or_name: str | os.PathLike[str]) -> Schedule:
    """Load a schedule from a `.sched` path, or by bundled name (`"human"`, `"human.sched"`).

    A file in the current directory wins over a bundled schedule of the same name.
    """
    path = resolve(path_or_name)
    try:
        text = read_text(path)
    except OSError as error:
        raise ScheduleError(f"cannot read the file: {error.strerror}", path=str(path_or_name)) from None
    shown = str(path_or_name) if Path(path_or_name).is_file() else str(path)
    return parse(text, path=shown)
