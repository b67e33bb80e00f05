"""A task's anatomy: the actuators and links a schedule's channels can name, and their groups.

`Anatomy` names the parts of a task's body in the order of Brax's `sys` (actuator i by the
joint it drives, link j), and groups of them (`left_leg`), without importing JAX or Brax,
so that a schedule's channels can be checked against a task, and listed, before anything is
built. A target in a channel's `[...]` is a name or a group of the part its kind scales
(`gear`: actuators, `mass`: links).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from smol_dsl.language.channels import CHANNEL_KINDS, Channel

PARTS = ("actuators", "links")
"""The parts of a body that channels name, as `ChannelKind.part` says."""


@dataclass(frozen=True)
class Anatomy:
    """The parts of a task's body that channels can name, in the order of Brax's `sys`.

    `actuators[i]` names actuator i (by the joint it drives), `links[j]` link j; groups name
    several at once (`left_leg`). A target in `[...]` is a name or a group of the kind's part.
    """

    actuators: tuple[str, ...]
    links: tuple[str, ...]
    actuator_groups: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    link_groups: Mapping[str, tuple[str, ...]] = field(default_factory=dict)

    def names(self, part: str) -> tuple[str, ...]:
        return self.actuators if part == "actuators" else self.links

    def groups(self, part: str) -> Mapping[str, tuple[str, ...]]:
        return self.actuator_groups if part == "actuators" else self.link_groups

    def targets(self) -> dict[str, tuple[str, ...]]:
        """Every name a channel's targets may use, per part: the part's names, then its groups
        (what `Schedule.check_targets` checks a file against)."""
        return {part: (*self.names(part), *self.groups(part)) for part in PARTS}

    def listing(self) -> dict[str, str]:
        """What each part holds, in words, for messages (`describe_part`)."""
        return {part: self.describe_part(part) for part in PARTS}

    def unknown_targets(self, channel: Channel) -> tuple[str, ...]:
        """The channel's targets that are neither a name nor a group of its kind's part."""
        part = CHANNEL_KINDS[channel.kind].part
        if part is None:
            return channel.targets
        known = set(self.targets()[part])
        return tuple(target for target in channel.targets if target not in known)

    def indices(self, channel: Channel) -> tuple[int, ...] | None:
        """Which actuators or links the channel scales (sorted), or None for all of them
        (and for friction and gravity); ValueError for a target the body lacks."""
        part = CHANNEL_KINDS[channel.kind].part
        if part is None or not channel.targets:
            return None
        unknown = self.unknown_targets(channel)
        if unknown:
            raise ValueError(f"{channel.name}: no {part} named {', '.join(unknown)}; {self.describe_part(part)}")
        names, groups = self.names(part), self.groups(part)
        chosen: set[int] = set()
        for target in channel.targets:
            for name in groups.get(target, (target,)):
                chosen.add(names.index(name))
        return tuple(sorted(chosen))

    def part_names(self, kind: str) -> tuple[str, ...]:
        """What a kind's resolved factors are per: the actuators (gear), the links (mass), or
        the whole body (friction, gravity: one factor, named as the kind)."""
        part = CHANNEL_KINDS[kind].part
        return self.names(part) if part is not None else (kind,)

    def describe_part(self, part: str) -> str:
        """`actuators: a, b, c; groups: left_leg (a, b)`: what a channel of this part can name."""
        text = f"{part}: {', '.join(self.names(part))}"
        groups = self.groups(part)
        if groups:
            text += "; groups: " + ", ".join(f"{g} ({', '.join(members)})" for g, members in groups.items())
        return text


def resolve(anatomy: Anatomy | None, factors: Mapping[Channel, float]) -> dict[str, tuple[float, ...]]:
    """The factor each part of the body gets from channels' factors: per kind, the product of
    the factors of the kind's channels that reach each actuator (gear), link (mass) or the
    whole body (friction, gravity), as the physics multiplies them (`tasks.body`). Kinds no
    channel scales are left out; without an anatomy (`None`) only channels without targets
    can be resolved, and gear and mass are one factor for the whole body.

    >>> from smol_dsl.tasks import task_spec
    >>> from smol_dsl.language.channels import Channel
    >>> walker = task_spec("walker2d").anatomy
    >>> resolve(walker, {Channel("mass"): 2.0, Channel("mass", ("torso",)): 0.5})["mass"][:2]
    (1.0, 2.0)
    """
    resolved: dict[str, list[float]] = {}
    for channel, factor in factors.items():
        if anatomy is None:
            if channel.targets:
                raise ValueError(f"{channel.name}: a body without an anatomy has no parts to name")
            names: tuple[str, ...] = (channel.kind,)
            reached = None
        else:
            names = anatomy.part_names(channel.kind)
            reached = anatomy.indices(channel)
        parts = resolved.setdefault(channel.kind, [1.0] * len(names))
        for index in range(len(names)) if reached is None else reached:
            parts[index] *= factor
    return {kind: tuple(parts) for kind, parts in resolved.items()}


def resolved_names(anatomy: Anatomy | None, kind: str) -> tuple[str, ...]:
    """The parts `resolve` gives a kind's factors for, in order."""
    return anatomy.part_names(kind) if anatomy is not None else (kind,)


def same_body(a: Mapping[str, tuple[float, ...]], b: Mapping[str, tuple[float, ...]]) -> bool:
    """Whether two resolved bodies are the same robot: every part's factor equal (up to the
    rounding of multiplying the same factors in another order), a kind one of them leaves
    out being 1 throughout."""
    for kind in {*a, *b}:
        size = len(a[kind] if kind in a else b[kind])
        mine, theirs = a.get(kind, (1.0,) * size), b.get(kind, (1.0,) * size)
        if len(mine) != len(theirs) or not all(math.isclose(x, y, rel_tol=1e-12) for x, y in zip(mine, theirs)):
            return False
    return True
