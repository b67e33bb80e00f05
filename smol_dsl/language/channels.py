"""Channels: the physical parameters a schedule can change, and the bodies that have them.

A `.sched` file schedules one or more channels, each a factor on one physical parameter of
the task's body, 1 being the standard body:

- `gear`: every actuator's gear, so its strength (the paper's alpha); `gear[left_leg]` or
  `gear[thigh_joint, leg_joint]`: only those actuators (a name, or a group of the task);
- `mass`: every link's mass and rotational inertia, scaled together so that the body stays
  physical (as if its density changed); `mass[torso]`: only those links;
- `friction`: the friction of every contact (Brax takes the larger of the two geoms'
  coefficients, and every geom's is scaled, so the ground's contacts scale by the factor);
- `gravity`: the gravity vector.

Factors multiply: an actuator under `gear` and `gear[left_leg]` gets their product.
A channel's targets are names; which names a body has is the task's business
(`smol_dsl.tasks.Anatomy`): the language checks targets against the names it is given.
Targets are a set: however a file or a caller orders them, a channel holds them sorted, so
`mass[torso, thigh]` and `mass[thigh,torso]` are one channel, with one name (in metrics
columns and messages) and one random key.

>>> Channel.parse("mass[torso, thigh]").name
'mass[thigh,torso]'
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class ChannelKind:
    """One kind of physical parameter: its keyword, what `[...]` selects, what it scales."""

    keyword: str
    part: str | None  # "actuators" or "links": what targets in [...] name; None: no targets
    scales: str  # what the factor multiplies, for messages and docs


CHANNEL_KINDS: dict[str, ChannelKind] = {
    kind.keyword: kind
    for kind in (
        ChannelKind("gear", "actuators", "the actuators' gear (their strength)"),
        ChannelKind("mass", "links", "the links' mass and rotational inertia, together"),
        ChannelKind("friction", None, "the friction of every contact (the ground's included)"),
        ChannelKind("gravity", None, "gravity"),
    )
}

_CANONICAL = re.compile(r"^([a-z]+)(?:\[([^\[\]]+)\])?$")


@dataclass(frozen=True, order=True)
class Channel:
    """A scheduled parameter: a kind, and the actuators or links it is limited to (none: all).

    Its `name` is how metrics.csv columns, certificates and messages write it: `gear`,
    `gear[left_leg]`, `mass[thigh,torso]` (targets sorted, whatever order they are given in).
    """

    kind: str
    targets: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in CHANNEL_KINDS:
            raise ValueError(f"{self.kind!r} is not a channel kind; the kinds are {', '.join(CHANNEL_KINDS)}")
        if isinstance(self.targets, str) or not all(isinstance(target, str) for target in self.targets):
            raise TypeError(f"a channel's targets are a tuple of names, not {self.targets!r}")
        if self.targets and CHANNEL_KINDS[self.kind].part is None:
            raise ValueError(f"{self.kind} takes no targets: it scales {CHANNEL_KINDS[self.kind].scales}")
        if len(set(self.targets)) != len(self.targets):
            repeated = next(target for target in self.targets if self.targets.count(target) > 1)
            raise ValueError(f"{self.kind}[...] names {repeated!r} twice; name each target once")
        object.__setattr__(self, "targets", tuple(sorted(self.targets)))

    @property
    def name(self) -> str:
        return f"{self.kind}[{','.join(self.targets)}]" if self.targets else self.kind

    @property
    def quantity(self) -> str:
        """How certificates and messages call its value: `alpha` for all actuators' gear (the
        paper's name), else the channel's name."""
        return "alpha" if self == GEAR else self.name

    @classmethod
    def parse(cls, name: str) -> Channel:
        """The channel a name writes (`mass`, `mass[torso, thigh]`: targets in any order, spaces
        allowed); TypeError for what is not a str, ValueError for a str that names no channel."""
        if not isinstance(name, str):
            raise TypeError(f"a channel is a Channel or its name as a str (e.g. 'mass[torso]'), not {name!r}")
        match = _CANONICAL.match(name.replace(" ", ""))
        if match is None or match.group(1) not in CHANNEL_KINDS:
            raise ValueError(f"{name!r} is not a channel; the channels are {', '.join(CHANNEL_KINDS)}")
        targets = tuple(match.group(2).split(",")) if match.group(2) else ()
        if "" in targets:
            raise ValueError(f"{name!r} is not a channel: a target between its commas is empty")
        return cls(match.group(1), targets)

    def __str__(self) -> str:
        return self.name


GEAR = Channel("gear")
"""Every actuator's gear: the paper's alpha, and the one channel of a file that declares none."""


def differing_finals(mine: Mapping[Any, float], theirs: Mapping[Any, float]) -> list[Any]:
    """The channels (keys, Channel or name) whose final values differ between two final bodies,
    in order of appearance; a channel a body does not list ends at 1 (the standard body)."""
    channels = dict.fromkeys([*mine, *theirs])
    return [channel for channel in channels if mine.get(channel, 1.0) != theirs.get(channel, 1.0)]
