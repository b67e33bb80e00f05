"""A body: a (C,) array of factors, one per scheduled channel, and the `sys` it makes.

Everywhere below the schedule a body is that array, for a tuple of channels; plain gear
alone (the paper's alpha) is the one-channel case `(GEAR,)`. A `Modulation` makes the hook
that turns a body into Brax's `System` (`Task.modulate`); each physics has its default
(`modulation_for`): MJX's is `tasks.mjx_body.mjx_modulation`, and spring's,
`modulation(anatomy, channels)`, multiplies the parameters of `sys` that the `spring`
pipeline reads:

- gear: `sys.actuator.gear` (`actuator.to_tau` multiplies the actuator's force, bias
  included, by it);
- mass: what the pipeline simulates as each link's mass and rotational inertia, together.
  Brax's spring (and positional) pipeline simulates `mass ** (1 - spring_mass_scale)` and
  `diag(i) ** (1 - spring_inertia_scale)` (`com.inv_inertia`): walker2d's scales are 0 and 1
  (real masses, unit inertia), halfcheetah's 0.3 and 0.8, hopper's and the ant's 1 and 1
  (every link weighs 1, whatever `sys` says). So the simulated values are written into
  `sys` with both scales 0, times the factor: on every task, a factor k makes the simulated
  body k times as heavy and as hard to turn. The pipeline caches the masses in its state at
  reset: `Task.rollout` gives the episode start the changed body's (`base.start_in_body`);
- friction: `sys.geom_friction` of every geom (and `pair_friction` of explicit pairs);
  spring's collision reads the sliding coefficient of a contact's geoms;
- gravity: `sys.gravity`, which the spring pipeline reads.

Factors of channels of the same kind multiply: an actuator under `gear` and
`gear[left_leg]` gets their product. Only multiplications (and selecting a factor per
actuator or link), so `modulation(anatomy, (GEAR,))(sys, body)` is bit for bit
`scale_gear(sys, body[0])`, and a body of ones leaves `sys` as it is.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from smol_dsl.language.channels import CHANNEL_KINDS, Channel
from smol_dsl.tasks.physics import check_physics

if TYPE_CHECKING:
    from brax.base import System

    from smol_dsl.tasks.anatomy import Anatomy

Modulate = Callable[["System", jax.Array], "System"]
"""(sys, body) -> the sys a rollout runs in, for a (C,) body of the task's channels (Brax
keeps every physics parameter in `sys`, as its `randomization_fn` does)."""

Modulation = Callable[["Anatomy | None", tuple[Channel, ...]], Modulate]
"""(anatomy, channels) -> the `Modulate` hook of a body under those channels: what a task
uses to change its body (`Task.modulation`; `modulation` below by default)."""


def scale_gear(sys: System, factor: jax.Array) -> System:
    """`sys` with every actuator's gear multiplied by `factor` (a scalar, or one per
    actuator; traced or not)."""
    return sys.replace(actuator=sys.actuator.replace(gear=sys.actuator.gear * factor))


def kind_factor(
    anatomy: Anatomy | None, channels: Sequence[Channel], body: jax.Array, kind: str, size: int
) -> jax.Array | None:
    """The factor the physics gives each of a kind's `size` parts (actuators for gear, links
    for mass, 1 for friction and gravity): the product, in channel order, of the factors of
    the kind's channels that reach it; a scalar (every channel covers all), a (size,) array
    (some cover only a part), or None (no channel of this kind). What `modulation` multiplies
    `sys` by, and what `tasks.ranges` bounds."""
    factor: jax.Array | None = None
    for c, channel in enumerate(channels):
        if channel.kind != kind:
            continue
        indices = anatomy.indices(channel) if anatomy is not None else None
        value = body[c]
        if indices is not None:
            chosen = np.zeros(size, dtype=bool)
            chosen[list(indices)] = True
            value = jnp.where(chosen, value, jnp.ones((), value.dtype))
        factor = value if factor is None else factor * value
    return factor


def check_channels(anatomy: Anatomy | None, channels: Sequence[Channel]) -> tuple[Channel, ...]:
    """The channels as a tuple, or a ValueError for none, an unknown kind, a target the
    anatomy lacks, or any target without an anatomy."""
    channels = tuple(channels)
    if not channels:
        raise ValueError("no channels: a body needs at least one scheduled parameter")
    for channel in channels:
        if channel.kind not in CHANNEL_KINDS:
            raise ValueError(f"{channel.name}: unknown channel kind; the kinds are {', '.join(CHANNEL_KINDS)}")
        if anatomy is None:
            if channel.targets:
                raise ValueError(f"{channel.name}: the task lists no anatomy, so a channel cannot name its parts")
            continue
        unknown = anatomy.unknown_targets(channel)
        if unknown:
            part = CHANNEL_KINDS[channel.kind].part
            where = anatomy.describe_part(part) if part else f"{channel.kind} applies to the whole body"
            raise ValueError(f"{channel.name}: cannot select {', '.join(unknown)}; {where}")
    return channels


Write = Callable[["System", jax.Array], "System"]
"""(sys, factor) -> the sys with one kind's factor written into the fields a physics reads:
a scalar or one per part (`kind_factor`); per link, (L,), for mass."""


def written_body(
    anatomy: Anatomy | None,
    channels: Sequence[Channel],
    parts: Callable[[System], tuple[int, int]],
    writes: Mapping[str, Write],
) -> Modulate:
    """The hook of a body under `channels` for a physics that reads it as `writes` says: per
    kind, in their order, the `Write` of the kind's factor (`kind_factor`; skipped where no
    channel is of that kind); `parts(sys)` counts the sys's actuators and links, which must be
    the anatomy's. Each physics' default `Modulation` is this with its own writes."""
    channels = check_channels(anatomy, channels)

    def modulate(sys: System, body: jax.Array) -> System:
        actuators, links = parts(sys)
        if anatomy is not None and (actuators, links) != (len(anatomy.actuators), len(anatomy.links)):
            raise ValueError(
                f"the anatomy has {len(anatomy.actuators)} actuators and {len(anatomy.links)} links; this sys has "
                f"{actuators} and {links}"
            )
        sizes = {"gear": actuators, "mass": links, "friction": 1, "gravity": 1}
        for kind, write in writes.items():
            factor = kind_factor(anatomy, channels, body, kind, sizes[kind])
            if factor is not None:
                sys = write(sys, jnp.broadcast_to(factor, (links,)) if kind == "mass" else factor)
        return sys

    return modulate


def scale_friction(sys: System, factor: jax.Array) -> System:
    """`sys` with every geom's friction coefficients (and explicit pairs') times `factor`:
    what spring's collision and MJX's read alike."""
    return sys.replace(geom_friction=sys.geom_friction * factor, pair_friction=sys.pair_friction * factor)


def modulation(anatomy: Anatomy | None, channels: Sequence[Channel]) -> Modulate:
    """The hook of a body under `channels` on spring: (sys, body (C,)) -> the changed sys.

    `anatomy` names the actuators and links of `sys` (in its order); without one, only
    channels without targets can be scheduled. The body may be traced.
    """
    return written_body(anatomy, channels, _spring_parts, SPRING_WRITES)


def _spring_parts(sys: System) -> tuple[int, int]:
    return sys.actuator.gear.shape[0], sys.link.inertia.mass.shape[0]


def _scale_mass(sys: System, factor: jax.Array) -> System:
    """The body the pipeline simulates, with every link's mass and rotational inertia times
    its factor (L,): the simulated values, `x ** (1 - spring_*_scale)`, written into sys with
    both scales 0 (at factor 1 the simulation is unchanged, bit for bit)."""
    inertia = sys.link.inertia
    mass = inertia.mass ** (1 - sys.spring_mass_scale) * factor
    diagonal = jnp.diagonal(inertia.i, axis1=-2, axis2=-1) ** (1 - sys.spring_inertia_scale) * factor[:, None]
    i = diagonal[..., None] * jnp.eye(3, dtype=diagonal.dtype)  # the pipeline reads the diagonal only
    zero = jnp.zeros((), jnp.result_type(sys.spring_mass_scale))
    link = sys.link.replace(inertia=inertia.replace(mass=mass, i=i))
    return sys.replace(link=link, spring_mass_scale=zero, spring_inertia_scale=zero)


SPRING_WRITES: dict[str, Write] = {
    "gear": scale_gear,
    "mass": _scale_mass,
    "friction": scale_friction,
    "gravity": lambda sys, factor: sys.replace(gravity=sys.gravity * factor),
}
"""What the spring pipeline reads of each kind (module docstring)."""


def modulation_for(physics: str) -> Modulation:
    """The default `Modulation` of a physics (`tasks.physics`): `modulation` for spring,
    `tasks.mjx_body.mjx_modulation` for MJX."""
    if physics == "mjx":
        from smol_dsl.tasks.mjx_body import mjx_modulation

        return mjx_modulation
    check_physics(physics)
    return modulation
