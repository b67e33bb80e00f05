"""`Schedule`: a verified, compiled `.sched` file, and `parse` / `load` to get one."""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import sympy as sp

from smol_dsl.errors import ScheduleError, Span
from smol_dsl.resources import library_dir, library_names
from smol_dsl.symbolic import SymbolicProgram, SymbolicSegment, compile_program, percent
from smol_dsl.syntax import parse_program
from smol_dsl.verify import Certificate, tail_start, verify

if TYPE_CHECKING:
    import jax

RANDOM_BIN_TOLERANCE = 1e-4
"""Float t within this many bins below a bin edge counts as on the edge (absorbs rounding)."""


def _fraction(value: sp.Rational) -> Fraction:
    return Fraction(int(value.p), int(value.q))


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
        self._evaluators: list[Callable[..., Any]] | None = None
        self._phase_alphas_compiled: dict[int, Callable[..., Any]] = {}

    # ------------------------------------------------------------------ symbolic
    @property
    def symbolic(self) -> sp.Piecewise:
        """alpha(t) as one exact sympy Piecewise in `smol_dsl.symbolic.T`."""
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
        starts = jnp.asarray([float(s.start) for s in self.segments[1:]], dtype=t.dtype)
        index = jnp.searchsorted(starts, t, side="right")
        bins = [self._bin_of(segment, t) for segment in self.segments]
        return self._select(t, index, bins, key)

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
        index = jnp.asarray(segment_of)[k]
        bins = [jnp.asarray(bin_of[j])[k] for j in range(len(self.segments))]
        return self._select(t, index, bins, key)

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
        return [
            None if s.random is None else jax.random.uniform(jax.random.fold_in(key, s.index), (s.random.count,))
            for s in self.segments
        ]

    # ------------------------------------------------------------------ internals
    def _bin_of(self, segment: SymbolicSegment, t: jax.Array) -> jax.Array | None:
        import jax.numpy as jnp

        if segment.random is None:
            return None
        position = (t - float(segment.start)) / float(segment.random.every)
        bins = jnp.floor(position + RANDOM_BIN_TOLERANCE).astype(jnp.int32)
        return jnp.clip(bins, 0, segment.random.count - 1)

    def _phase_tables(self, num_phases: int) -> tuple[np.ndarray, list[np.ndarray]]:
        _check_phases(num_phases)
        starts = [_fraction(s.start) for s in self.segments]
        segment_of = np.zeros(num_phases, dtype=np.int32)
        bin_of = [np.zeros(num_phases, dtype=np.int32) for _ in self.segments]
        for k in range(num_phases):
            t = Fraction(k, num_phases)
            j = max(i for i, s in enumerate(starts) if s <= t)
            segment_of[k] = j
            random = self.segments[j].random
            if random is not None:
                bin_of[j][k] = min(math.floor((t - starts[j]) / _fraction(random.every)), random.count - 1)
        return segment_of, bin_of

    def _select(self, t: jax.Array, index: jax.Array, bins: list[jax.Array | None], key: Any) -> jax.Array:
        import jax.numpy as jnp

        evaluators = self._compiled()
        draws = self.draws(key) if any(s.random is not None for s in self.segments) else None
        values = []
        for j, (segment, evaluate) in enumerate(zip(self.segments, evaluators)):
            inside = jnp.clip(t, float(segment.start), float(segment.end))
            if segment.random is not None:
                assert draws is not None and bins[j] is not None
                low, high = float(segment.random.low), float(segment.random.high)
                values.append(low + (high - low) * draws[j][bins[j]])
            else:
                values.append(evaluate(inside))
        values = [jnp.broadcast_to(v, t.shape).astype(t.dtype) for v in values]
        if len(values) == 1:
            return values[0]
        return jnp.select([index == j for j in range(len(values))], values, default=values[-1])

    def _compiled(self) -> list[Callable[..., Any]]:
        if self._evaluators is None:
            from smol_dsl.jaxify import bell, to_jax

            def evaluator(segment: SymbolicSegment) -> Callable[..., Any] | None:
                if _fraction(segment.start) >= self.tail_start:
                    # proven identically 1 (say sin(t)**2 + cos(t)**2): exactly 1.0 in floats too
                    return to_jax(sp.Integer(1))
                if segment.bell is not None:
                    return bell(segment.bell, float(segment.start), float(segment.end))
                return None if segment.random else to_jax(segment.pieces[0].expr)

            self._evaluators = [evaluator(s) for s in self.segments]
        return self._evaluators

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
