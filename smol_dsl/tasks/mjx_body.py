"""A body on MJX: the default `Modulation` of a task simulated by MuJoCo's MJX.

MJX reads a model's fields as MuJoCo does, so a body writes these (`tasks.body.kind_factor`
gives each part its factor, the product of the channels that reach it; body = link + 1,
body 0 being the world):

- gear: `actuator_gear` (every component: MuJoCo's joint transmission multiplies the
  actuator's force by the first, the others are 0 for a hinge);
- mass: `body_mass` and `body_inertia` of each link times its factor, a body k times as heavy
  and as hard to turn, as on spring; and the constants MuJoCo derives from them when it
  compiles a model (`mj_setConst`), which MJX reads but never recomputes: `body_invweight0`
  and `dof_invweight0`, the inverse weights that scale each constraint's softness to the
  body it acts on (without them a heavier body would sink further into the floor). They are
  recomputed here in JAX, as MuJoCo does, at the model's reference pose (`invweights`);
- friction: `geom_friction` of every geom (and `pair_friction` of explicit pairs): MJX's
  collision gives a contact the larger of its two geoms' coefficients, or the priority
  geom's, so every contact's friction is scaled by k exactly;
- gravity: `opt.gravity`.

Only multiplications and selections, except the inverse weights; a body of ones leaves the
model as it is, bit for bit (the inverse weights are kept where every link's factor is 1).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from smol_dsl.tasks.body import Modulate, Write, scale_friction, written_body

if TYPE_CHECKING:
    from brax.base import System

    from smol_dsl.language.channels import Channel
    from smol_dsl.tasks.anatomy import Anatomy

MINIMUM_INVERSE_WEIGHT = 1e-15  # MuJoCo's mjMINVAL, its floor for an inverse weight


def mjx_modulation(anatomy: Anatomy | None, channels: Sequence[Channel]) -> Modulate:
    """The hook of a body under `channels` on MJX: (sys, body (C,)) -> the changed sys, with
    the fields MJX reads scaled (module docstring). The body may be traced."""
    return written_body(anatomy, channels, _mjx_parts, MJX_WRITES)


def _mjx_parts(sys: System) -> tuple[int, int]:
    return sys.actuator_gear.shape[0], sys.body_mass.shape[0] - 1  # body 0 is the world


def scale_mass(sys: System, factor: jax.Array) -> System:
    """`sys` with every link's mass and rotational inertia times its factor (L,), and the
    inverse weights of the heavier or lighter body; where every factor is 1, the model's
    own inverse weights, bit for bit."""
    one = jnp.ones((1,), factor.dtype)
    per_body = jnp.concatenate([one, factor])  # the world keeps its (zero) mass
    scaled = sys.replace(body_mass=sys.body_mass * per_body, body_inertia=sys.body_inertia * per_body[:, None])
    body_invweight, dof_invweight = invweights(scaled)
    unchanged = jnp.all(factor == 1)
    return scaled.replace(
        body_invweight0=jnp.where(unchanged, sys.body_invweight0, body_invweight),
        dof_invweight0=jnp.where(unchanged, sys.dof_invweight0, dof_invweight),
    )


def invweights(sys: System) -> tuple[jax.Array, jax.Array]:
    """The inverse weights MuJoCo derives from a model's masses when it compiles it
    (`mj_setConst`), at the reference pose `qpos0`: per body, the mean of the diagonal of
    J M⁻¹ Jᵀ for the translation and for the rotation of its centre of mass (J its Jacobian,
    M the joint-space inertia, armature included), 0 for bodies welded to the world; per
    degree of freedom, the diagonal of M⁻¹, averaged over the translations and over the
    rotations of a free joint and over the rotations of a ball joint."""
    from mujoco import mjx

    data = mjx.make_data(sys).replace(qpos=sys.qpos0)
    data = mjx.crb(sys, mjx.com_pos(sys, mjx.kinematics(sys, data)))
    inverse_m = jnp.linalg.inv(mjx.full_m(sys, data))

    def body_weight(body: jax.Array) -> jax.Array:
        jacp, jacr = mjx.jac(sys, data, data.xipos[body], body)  # (nv, 3) each
        translation = jnp.trace(jacp.T @ inverse_m @ jacp) / 3
        rotation = jnp.trace(jacr.T @ inverse_m @ jacr) / 3
        return jnp.maximum(MINIMUM_INVERSE_WEIGHT, jnp.stack([translation, rotation]))

    bodies = jnp.arange(sys.nbody)
    movable = jnp.asarray(np.asarray(sys.body_weldid) != 0)[:, None]
    body_invweight = jnp.where(movable, jax.vmap(body_weight)(bodies), 0.0)
    return body_invweight, _dof_invweights(sys, jnp.diagonal(inverse_m))


def _dof_invweights(sys: System, diagonal: jax.Array) -> jax.Array:
    """Each degree of freedom's inverse weight from the diagonal of M⁻¹, averaged within a
    free joint's translations and rotations and a ball joint's rotations."""
    from mujoco import mjx

    groups = np.arange(sys.nv)  # the group of dofs each dof's weight is averaged over
    for joint, kind in enumerate(np.asarray(sys.jnt_type)):
        first = int(sys.jnt_dofadr[joint])
        if kind == mjx.JointType.FREE:
            groups[first : first + 3] = first
            groups[first + 3 : first + 6] = first + 3
        elif kind == mjx.JointType.BALL:
            groups[first : first + 3] = first
    counts = np.bincount(groups, minlength=sys.nv)
    sums = jax.ops.segment_sum(diagonal, jnp.asarray(groups), num_segments=sys.nv)
    return jnp.maximum(MINIMUM_INVERSE_WEIGHT, sums[groups] / counts[groups])


MJX_WRITES: dict[str, Write] = {
    "gear": lambda sys, factor: sys.replace(actuator_gear=sys.actuator_gear * jnp.reshape(factor, (-1, 1))),
    "mass": scale_mass,
    "friction": scale_friction,
    "gravity": lambda sys, factor: sys.replace(opt=sys.opt.replace(gravity=sys.opt.gravity * factor)),
}
"""What MJX reads of each kind (module docstring)."""
