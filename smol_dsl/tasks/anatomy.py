"""A task's anatomy: the actuators and links a schedule's channels can name, and their groups.

`Anatomy` names the parts of a task's body in the order of Brax's `sys` (actuator i by the
joint it drives, link j), and groups of them (`left_leg`), without importing JAX or Brax,
so that a schedule's channels can be checked against a task, and listed, before anything is
built. A target in a channel's `[...]` is a name or a group of the part its kind scales
(`gear`: actuators, `mass`: links).
"""

from __future__ import annotations

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

    def describe_part(self, part: str) -> str:
        """`actuators: a, b, c; groups: left_leg (a, b)`: what a channel of this part can name."""
        text = f"{part}: {', '.join(self.names(part))}"
        groups = self.groups(part)
        if groups:
            text += "; groups: " + ", ".join(f"{g} ({', '.join(members)})" for g, members in groups.items())
        return text
