"""A compiled schedule in plain JAX: alpha per phase, jitted with the phase traced, and as an
optax-style schedule of the step count.

Run: python examples/use_with_jax.py

For a QDax algorithm under a schedule (scoring in a body, re-evaluation at phase
boundaries), see examples/qdax_map_elites.py, qdax_pga_me.py and qdax_cma_me.py.
"""

import jax
import jax.numpy as jnp

import smol_dsl

schedule = smol_dsl.load("human")
print(repr(schedule))
print(schedule.certificate)

num_phases = 100
key = jax.random.key(42)

# alpha for each phase, as the runner uses it
alphas = schedule.phase_alphas(num_phases, key)
print("phase 0, 30, 89, 90:", [round(float(alphas[k]), 4) for k in (0, 30, 89, 90)])


# inside a jitted training step, the phase index can be traced: one compilation for all phases
@jax.jit
def scaled_gear(gear: jax.Array, phase: jax.Array) -> jax.Array:
    return gear * schedule.phase_alpha(phase, num_phases, key)


gear = jnp.array([100.0, 100.0, 100.0])
for phase in (0, 30, 95):
    print(f"phase {phase:3d}: gear {scaled_gear(gear, phase)}")

# an optax-style schedule of the step count (here: 10 generations per phase)
by_generation = schedule.as_optax(total_steps=1000, num_phases=num_phases)
print("generation 305:", float(by_generation(305)))
