"""`Schedule`: a verified, compiled `.sched` file of one or more channels, and `parse` /
`load` to get one."""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import replace
from fractions import Fraction
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from smol_dsl.errors import Message, ScheduleError, Setting, Span
from smol_dsl.language.assembly import parse_program
from smol_dsl.language.channels import GEAR, Channel, differing_finals
from smol_dsl.language.compiler import compile_program
from smol_dsl.language.curve import Curve, check_phases
from smol_dsl.language.library import library_dir, library_names
from smol_dsl.language.pacing import Pacing
from smol_dsl.language.pacing_certificate import envelope_text, pacing_text
from smol_dsl.language.symbolic import SymbolicCurve, SymbolicProgram, SymbolicSegment, percent
from smol_dsl.language.targets import check_targets
from smol_dsl.language.verify import verify

# JAX is imported inside the methods that evaluate: parsing and checking a schedule never load it.
if TYPE_CHECKING:
    import jax
    import sympy as sp

    from smol_dsl.language.certificates import Certificate

_CONSTANT_TEXT = "0% .. 100%: tail\n"
_LONE_CR = re.compile(r"\r(?!\n)")


@lru_cache(maxsize=64)
def constant_curve(channel: Channel = GEAR) -> Curve:
    """The curve of a channel a file does not declare: 1 throughout (the standard body)."""
    program = compile_program(parse_program(_CONSTANT_TEXT))
    symbolic = program.curves[0]
    certificate = verify(program)[GEAR]
    if channel != GEAR:
        symbolic = replace(symbolic, channel=channel)
        certificate = replace(certificate, channel=channel)
    return Curve(symbolic, certificate, _CONSTANT_TEXT, None)


class Schedule:
    """A verified schedule: for each of its channels, a factor over training progress t in [0, 1].

    Get one with `smol_dsl.load("human")` or `smol_dsl.parse(text)`. A file without a
    `channel` line schedules one channel, `gear` (alpha, the paper's actuator scaling).
    `curve(channel)` is one channel's `Curve`; `alpha`, `phase_alpha(s)`, `as_optax`, `draws`,
    `symbolic`, `segments` and `certificate` are plain gear's, which is 1 throughout in a file
    that does not schedule it. Everything that evaluates is pure and jittable:

    >>> import jax, smol_dsl
    >>> smol = smol_dsl.load("smol")
    >>> float(smol.alpha(0.0)), float(smol.alpha(0.95))
    (1.5, 1.0)
    >>> smol.phase_alphas(100, jax.random.key(0)).shape
    (100,)
    >>> smol_dsl.load("growth").phase_values(100).shape  # one column per channel
    (100, 2)
    """

    def __init__(
        self, program: SymbolicProgram, certificates: dict[Channel, Certificate], source: str, path: str | None
    ):
        self._program = program
        self.source: str = source
        self.path: str | None = path
        stem = Path(path).stem if path else None
        self.name: str = program.name or stem or "schedule"
        self.description: str = program.description or ""
        self.extinction: float = float(program.extinction)
        self._curves: dict[Channel, Curve] = {
            curve.channel: Curve(curve, certificates[curve.channel], source, path) for curve in program.curves
        }
        self._symbolic: dict[Channel, SymbolicCurve] = {curve.channel: curve for curve in program.curves}
        self.tail_start: Fraction = max(curve.tail_start for curve in self._curves.values())
        """Where every channel is at its final value for good: the latest of their tails' starts."""
        self.pacing: Pacing | None = program.pacing
        """The file's `pace` lines (None: every channel follows the budget's phases)."""

    # ------------------------------------------------------------------ channels
    @property
    def channels(self) -> tuple[Channel, ...]:
        """The scheduled channels, in the order the file declares them (`(GEAR,)` without any)."""
        return tuple(self._curves)

    def curve(self, channel: Channel | str = GEAR, *, or_standard: bool = False) -> Curve:
        """One declared channel's curve, by `Channel` or name (`"mass"`, `"mass[torso, thigh]"`:
        targets in any order). ValueError for a channel the file does not declare, unless
        `or_standard`: then it is the standard body's, 1 throughout (as `alpha` is for a file
        that does not schedule plain gear)."""
        channel = _as_channel(channel)
        found = self._curves.get(channel)
        if found is not None:
            return found
        if or_standard:
            return constant_curve(channel)
        raise ValueError(
            f"schedule {self.name!r} declares no channel {channel.name}; it declares "
            f"{', '.join(c.name for c in self.channels)} (curve(..., or_standard=True) gives 1 for any other)"
        )

    @property
    def certificates(self) -> dict[Channel, Certificate]:
        """Each declared channel's certificate, in declared order."""
        return {channel: curve.certificate for channel, curve in self._curves.items()}

    def certificates_text(self) -> str:
        """The certificates as `smol-dsl check` prints them: one per channel, each under a
        `channel NAME:` line when there are several, then the pacing's."""
        if len(self._curves) == 1:
            text = str(next(iter(self._curves.values())).certificate)
        else:
            text = "\n".join(f"channel {channel.name}:\n{curve.certificate}" for channel, curve in self._curves.items())
        return text + ("\n" + pacing_text(self) if self.pacing is not None else "")  # each clock's proofs

    @property
    def final_body(self) -> dict[Channel, float]:
        """Each declared channel's final value: the body the run ends on (1: the standard one)."""
        return {channel: curve.final for channel, curve in self._curves.items()}

    def final_differences(self, other: Schedule) -> list[str]:
        """The names of the channels whose final values differ between the two schedules (a
        channel a file does not declare ends at 1), in declared order: empty when both end on
        the same body, so that their runs compare."""
        if not isinstance(other, Schedule):
            raise TypeError(f"final_differences takes a Schedule (e.g. smol_dsl.load('leg-damage')), not {other!r}")
        return [channel.name for channel in differing_finals(self.final_body, other.final_body)]

    def check_targets(
        self, targets: Mapping[str, Collection[str]] | None, task: str, listing: Mapping[str, str] | None = None
    ) -> None:
        """Refuse, with a located ScheduleError, a channel target not among `targets[part]`
        ("actuators", "links": every name and group of the task's body), or any target for
        `targets` None; `listing[part]` says what the task `task` has, for the hint
        (`smol_dsl.tasks.Anatomy.targets` and `listing` give both)."""
        check_targets(self, targets, task, listing)

    # ------------------------------------------------------------------ all channels in JAX
    def phase_value(
        self,
        k: jax.typing.ArrayLike,
        num_phases: int,
        key: jax.Array | None = None,
        channels: Sequence[Channel | str] | None = None,
    ) -> jax.Array:
        """Each channel's value during phase `k` of `num_phases`, shape `k.shape + (C,)` for
        `channels` (default `self.channels`; one the file does not declare is 1; a name stands for
        its channel). `k` may be traced."""
        import jax.numpy as jnp

        columns = []
        for channel in self._chosen(channels):
            if channel in self._curves:
                columns.append(self._curves[channel].phase_value(k, num_phases, key))
            else:
                columns.append(jnp.ones(jnp.shape(k), dtype=jnp.result_type(float)))
        return jnp.stack(columns, axis=-1)

    def phase_values(
        self, num_phases: int, key: jax.Array | None = None, channels: Sequence[Channel | str] | None = None
    ) -> jax.Array:
        """Each channel's value for every phase, shape (num_phases, C) for `channels` (default
        `self.channels`; one the file does not declare is 1.0 throughout). Column c is
        `curve(channels[c]).phase_values(num_phases, key)`, bit for bit."""
        import jax.numpy as jnp

        check_phases(num_phases)
        columns = []
        for channel in self._chosen(channels):
            if channel in self._curves:
                columns.append(self._curves[channel].phase_values(num_phases, key))
            else:
                columns.append(jnp.ones((num_phases,), dtype=jnp.result_type(float)))
        return jnp.stack(columns, axis=1)

    def checked_phase_values(
        self, num_phases: int, key: jax.Array | None = None, channels: Sequence[Channel | str] | None = None
    ) -> np.ndarray:
        """`phase_values` on the host, refused with a located ScheduleError if any value is not
        finite and positive (which the certificates prove cannot happen)."""
        chosen = self._chosen(channels)
        values = np.asarray(self.phase_values(num_phases, key, chosen))
        for column, channel in enumerate(chosen):
            self.curve(channel, or_standard=True).check_phase_values(values[:, column], num_phases)
        return values

    def _chosen(self, channels: Sequence[Channel | str] | None) -> tuple[Channel, ...]:
        """The channels a `channels` argument names: the file's for None; TypeError for a single
        name or what is not a sequence, ValueError for none or a channel given twice."""
        if channels is None:
            return self.channels
        if isinstance(channels, (str, Channel)) or not isinstance(channels, Sequence):
            raise TypeError(
                f"channels is a sequence of channels or names, e.g. ('mass', 'gear'), not {channels!r}"
                + (f"; for one channel write ({channels!r},)" if isinstance(channels, (str, Channel)) else "")
            )
        chosen = tuple(_as_channel(channel) for channel in channels)
        if not chosen:
            raise ValueError("channels is empty: name at least one channel, or pass None for the file's own")
        if len(set(chosen)) != len(chosen):
            repeated = next(channel for channel in chosen if chosen.count(channel) > 1)
            raise ValueError(f"channels names {repeated.name} twice (targets in any order are one channel)")
        return chosen

    def tail_phases(self, num_phases: int) -> int:
        """How many of `num_phases` equal phases lie wholly inside every channel's tail."""
        check_phases(num_phases)
        return num_phases - math.ceil(self.tail_start * num_phases)

    def tail_problem(self, num_phases: int) -> Message | None:
        """Why `num_phases` cannot train this schedule to its end (no phase lies wholly in
        its final-body tail, so the last phase is not the final body), naming the setting
        `num_phases` and the fewest phases that can; None when they can."""
        if self.tail_phases(num_phases) >= 1:
            return None
        least = next(n for n in range(1, 100_001) if self.tail_phases(n) >= 1)
        return (
            f"with {num_phases} phases no phase lies wholly in the final-body tail of {self.name} "
            f"(from {float(self.tail_start):.0%}), so the run would not end on its final body; use "
            + Setting("num_phases")
            + f" {least} or more"
        )

    # ------------------------------------------------------------------ pacing (language/pacing.py)
    @property
    def is_paced(self) -> bool:
        """Whether some channel waits for the archive (a `pace` line)."""
        return self.pacing is not None

    def clock_of(self, channel: Channel | str) -> int | None:
        """The index of the clock `channel` reads in `pacing.clocks`, or None (the budget's)."""
        channel = _as_channel(channel)
        if self.pacing is None or channel not in self._curves:
            return None
        return self.pacing.channel_clocks[list(self._curves).index(channel)]

    def tail_phase(self, num_phases: int) -> int:
        """The first of `num_phases` phases wholly in every channel's tail: from it on, the
        final body whatever a paced run's metrics did."""
        return num_phases - self.tail_phases(num_phases)

    def channel_tail_phases(self, num_phases: int, channels: Sequence[Channel | str] | None = None) -> tuple[int, ...]:
        """Per channel of `channels` (default the file's), the first phase wholly in its own
        tail (0 for a channel the file does not declare: it is 1 throughout)."""
        check_phases(num_phases)
        return tuple(
            math.ceil(self._curves[channel].tail_start * num_phases) if channel in self._curves else 0
            for channel in self._chosen(channels)
        )

    def phase_indices(
        self,
        development: jax.typing.ArrayLike,
        phase: jax.typing.ArrayLike,
        num_phases: int,
        channels: Sequence[Channel | str] | None = None,
    ) -> jax.Array:
        """Per channel of `channels` (default the file's), the open-loop phase whose value it
        has during `phase` given the clocks' `development` (K,): `phase` on the budget's clock
        or in its tail; 0 in a paced file for a channel it does not declare (1 throughout).
        A paced run's body is `phase_values(num_phases)[indices, column]`; jittable."""
        import jax.numpy as jnp

        chosen = self._chosen(channels)
        if self.pacing is None:
            return jnp.full((len(chosen),), jnp.asarray(phase, jnp.int32))
        pacing = Pacing(self.pacing.clocks, tuple(self.clock_of(channel) for channel in chosen))
        indices = pacing.indices(development, phase, self.channel_tail_phases(num_phases, chosen))
        return jnp.where(jnp.asarray([channel in self._curves for channel in chosen]), indices, 0)

    def envelope_text(self, num_phases: int) -> str:
        """Per phase of `num_phases`, each paced channel's lowest and highest development step
        and value whatever the metrics do, and the largest jump into the tail."""
        return envelope_text(self, num_phases)

    @property
    def is_random(self) -> bool:
        """Whether a segment of any channel draws random values (from the run's key)."""
        return any(segment.draws is not None for curve in self._curves.values() for segment in curve.segments)

    # ------------------------------------------------------------------ plain gear: the paper's alpha
    # The front door for plain gear: each is `curve(GEAR)`'s, the same per-channel evaluation
    # as `phase_values` (1 throughout in a file that does not schedule plain gear).
    @property
    def _gear(self) -> Curve:
        return self.curve(GEAR, or_standard=True)

    @property
    def certificate(self) -> Certificate:
        """Plain gear's certificate (alpha's)."""
        return self._gear.certificate

    @property
    def segments(self) -> tuple[SymbolicSegment, ...]:
        """Plain gear's segments."""
        return self._gear.segments

    @property
    def symbolic(self) -> sp.Piecewise:
        """alpha(t) as one exact sympy Piecewise in `smol_dsl.language.symbolic.T`."""
        return self._gear.symbolic

    def alpha(self, t: jax.typing.ArrayLike, key: jax.Array | None = None) -> jax.Array:
        """alpha at progress `t` (scalar or array, clipped to [0, 1]); jit- and vmap-able.

        Random segments draw from `key` (a fixed default key when None): the same key
        always gives the same schedule.
        """
        return self._gear.value(t, key)

    def phase_alpha(self, k: jax.typing.ArrayLike, num_phases: int, key: jax.Array | None = None) -> jax.Array:
        """alpha during phase `k` of `num_phases`: the curve at the phase's start, t = k / N.

        `k` may be traced (one compilation serves every phase); `num_phases` is static.
        Which segment and which random draw a phase gets is decided in exact rational
        arithmetic, so phase 90 of 100 is exactly at the 90% boundary.
        """
        return self._gear.phase_value(k, num_phases, key)

    def phase_alphas(self, num_phases: int, key: jax.Array | None = None) -> jax.Array:
        """alpha for every phase of `num_phases`, shape (num_phases,)."""
        return self._gear.phase_values(num_phases, key)

    def checked_phase_alphas(self, num_phases: int, key: jax.Array | None = None) -> np.ndarray:
        """`phase_alphas` on the host, refused with a ScheduleError if any is not finite and positive.

        The certificate proves this never happens; runners call it before training anyway, so
        that a defect can never waste a run.
        """
        return self._gear.checked_phase_values(num_phases, key)

    def as_optax(
        self, total_steps: int, *, num_phases: int | None = None, key: jax.Array | None = None
    ) -> Callable[[jax.typing.ArrayLike], jax.Array]:
        """An optax-style schedule: a function of the step count returning alpha.

        With `num_phases`, alpha is held constant within each of that many equal phases
        (as the runner does); otherwise it follows the smooth curve.

        >>> import smol_dsl
        >>> schedule = smol_dsl.load("smol").as_optax(1000, num_phases=100)
        >>> float(schedule(950))
        1.0
        """
        return self._gear.as_optax(total_steps, num_phases=num_phases, key=key)

    def draws(self, key: jax.Array | None = None) -> list[jax.Array | None]:
        """The uniform [0, 1) draws of each of plain gear's random segments under `key` (None elsewhere)."""
        return self._gear.draws(key)

    def __repr__(self) -> str:
        c = self.certificate
        segments = sum(len(curve.segments) for curve in self._curves.values())
        return (
            f"Schedule({self.name!r}, channels={', '.join(c.name for c in self.channels)}, segments={segments}, "
            f"alpha in [{c.minimum:.4g}, {c.maximum:.4g}], tail from {percent(self.tail_start)}, "
            f"extinction={self.extinction:g})"
        )


def _as_channel(channel: Channel | str) -> Channel:
    """A channel, or the channel a name writes (ValueError for a name that is no channel,
    TypeError for what is neither)."""
    return channel if isinstance(channel, Channel) else Channel.parse(channel)


def parse(text: str, *, path: str | os.PathLike[str] | None = None) -> Schedule:
    """Parse, compile and verify `.sched` text; raise `ScheduleError` if anything is wrong.

    Lines may end in LF, CRLF or a lone CR (old Mac files); a lone CR becomes LF in the
    schedule's `source`, so that line numbers are the ones an editor shows."""
    shown = str(path) if path is not None else None
    text = _LONE_CR.sub("\n", text)
    try:
        program = parse_program(text)
        symbolic = compile_program(program)
        certificates = verify(symbolic)
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
    return Schedule(symbolic, certificates, text, shown)


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
