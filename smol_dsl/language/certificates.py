"""The certificate: what verification proved about one channel of a schedule, as plain data.

Kept apart from `smol_dsl.language.verify` (the proof) so that what a proof gives, and how it
is printed and written to JSON, reads on its own: a `Certificate` per channel, with one
`PieceCertificate` per smooth piece and one `JoinCertificate` where segments meet.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import sympy as sp

from smol_dsl.language.channels import GEAR, Channel
from smol_dsl.language.symbolic import percent

if TYPE_CHECKING:
    from smol_dsl.language.prover import Monotone

MIN_TAIL = sp.Rational(1, 10)
"""The last 10% of the run must be at alpha = 1, or each channel at its final value (the
paper's fair-comparison rule)."""


@dataclass(frozen=True)
class PieceCertificate:
    """What was proven about one smooth piece of alpha(t)."""

    segment: int
    kind: str
    start: float
    end: float
    minimum: float
    maximum: float
    monotone: Monotone
    exact: bool  # False when extrema come from an interval enclosure
    float32_error: float = 0.0  # |float32 alpha - exact alpha| <= this, everywhere on the piece


@dataclass(frozen=True)
class JoinCertificate:
    """Continuity where one segment meets the next."""

    position: float
    continuous: bool
    jump: float | None  # None for a random segment (its value there is a random draw)


@dataclass(frozen=True)
class Certificate:
    """The result of verifying one channel of a schedule: bounds, tail, joins, and each piece.

    `str` writes its values as `alpha` for plain gear (the paper's name), else by the
    channel's name: `tail: mass == 0.5 from 90% ...`.
    """

    minimum: float
    maximum: float
    tail_start: float
    joins: tuple[JoinCertificate, ...]
    pieces: tuple[PieceCertificate, ...]
    bounds: tuple[float, float] | None
    extinction: float
    float32_error: float = 0.0
    channel: Channel = GEAR
    final: float = 1.0
    """The channel's value over its tail."""

    @property
    def tail_fraction(self) -> float:
        return 1.0 - self.tail_start

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary of the certificate (the channel as its name)."""
        data = asdict(self)
        data["channel"] = self.channel.name
        return json.loads(json.dumps(data))

    def __str__(self) -> str:
        q = self.channel.quantity
        lines = [
            f"  {q} in [{self.minimum:.6g}, {self.maximum:.6g}]   {q} > 0: proven"
            + (f"   bounds {self.bounds[0]:.6g} .. {self.bounds[1]:.6g}: proven" if self.bounds else ""),
            f"  tail: {q} == {self.final:.6g} from {percent(self.tail_start)} to 100% "
            f"({percent(self.tail_fraction)} of the run, at least {percent(MIN_TAIL)} required): proven",
            "  pieces:",
        ]
        for p in self.pieces:
            extent = f"{percent(p.start)} .. {percent(p.end)}"
            note = "" if p.exact else "  (interval enclosure)"
            lines.append(
                f"    #{p.segment:<2} {extent:<16} {p.kind:<15} {q} {p.minimum:.6g} .. {p.maximum:.6g}"
                f"   {p.monotone}{note}"
            )
        if self.joins:
            words = []
            for j in self.joins:
                if j.jump is None:
                    words.append(f"{percent(j.position)} random")
                elif j.continuous:
                    words.append(f"{percent(j.position)} continuous")
                else:
                    words.append(f"{percent(j.position)} jump {j.jump:+.6g}")
            lines.append("  joins: " + ", ".join(words))
        lines.append(f"  extinction: {self.extinction:g}")
        lines.append(f"  float32: every value finite, {q} within {self.float32_error:.2g} of exact and > 0: proven")
        return "\n".join(lines)
