"""Any QDax algorithm under a scheduled body, in QDax's own conventions.

>>> from smol_dsl import qdax as smol
>>> bodies = smol.phase_bodies("smol", 100, smol.schedule_key(0))  # what `run --seed 0` trains in
>>> bodies.shape  # a factor per channel (smol.sched: plain gear, the paper's alpha) per phase
(100, 1)
>>> [round(float(alpha), 3) for alpha in bodies[[0, 45, 99], 0]]
[1.5, 1.25, 1.0]

- `scoring_function(task, schedule)`: `score(genotypes, key, body) -> (fitnesses,
  descriptors, extra_scores)`, QDax's scoring function with the body a traced argument
  (`extra_scores["transitions"]` for PGA-ME's and DCRL-ME's emitters; `physics="mjx"`, or a
  task of `make_task(name, physics="mjx")`, simulates it on MuJoCo's MJX);
- `phase_bodies(schedule, num_phases, key)`: the (num_phases, C) bodies it takes;
- `reevaluate(repertoire, score, body, key, extinction)`: the phase-boundary step on any
  QDax repertoire;
- `new_phase(emitter_state, repertoire)`: the emitter's body-dependent state (CMA's
  `previous_fitnesses`, replay buffers) brought to the new phase;
- `run_start(task, seed, ...)`: the key, centroids and initial population of `smol-dsl run
  --seed`, so that a QDax loop follows its random streams; `phase_of_generation` splits
  the generations into phases as it does;
- `pacing_start(schedule, metrics)`, `pace(schedule, state, metrics, phase, num_phases)`,
  `settle`, `phase_body` and `body_moves`: a paced schedule's decision at each phase end, a
  pure function of its `PaceState` and QDax's metrics, and the body it reaches
  (`smol_dsl.qdax.pacing`; examples/qdax_map_elites.py drives one);
- `env_sizes(task)`: the `env` argument of QDax's gradient emitters;
- `compiler_options(task)`: the XLA options to jit your step with, for rollouts as fast as
  smol-dsl's own on CPUs (the same results, bit for bit).

Bind the body inside your jitted step, so that one compilation serves every phase:

    update = jax.jit(lambda r, e, k, body: MAPElites(functools.partial(score, body=body),
                                                      emitter, metrics).update(r, e, k),
                     compiler_options=smol.compiler_options(task))

Replacing the scoring function of a `MAPElites` whose `update` is already jitted does not
work: `jax.jit(map_elites.update)` traced the bound method once, the old scoring function
(and the body baked into it) inside, and keeps that program whatever the object holds later.

Importing it makes QDax 0.5's gradient emitters (PGA-ME, DCRL-ME, ...) importable with
Brax v2: they import a Brax v1 module for one annotation (`smol_dsl.qdax.compat`).

This layer sits on the schedule language and the tasks; the runner's engine scores and
re-evaluates with the same functions.
"""

from __future__ import annotations

from smol_dsl.qdax import compat
from smol_dsl.qdax.emitters import new_phase
from smol_dsl.qdax.pacing import body_moves, pace, pace_metrics, pacing_start, phase_body, settle
from smol_dsl.qdax.phases import phase_bodies, phase_of_generation
from smol_dsl.qdax.reevaluation import reevaluate
from smol_dsl.qdax.scoring import EnvSizes, RunStart, compiler_options, env_sizes, run_start, scoring_function
from smol_dsl.seeds import schedule_key

compat.install()  # QDax 0.5's PGA-ME and DCRL-ME emitters import a Brax v1 module (see compat.py)

__all__ = [
    "EnvSizes",
    "RunStart",
    "body_moves",
    "compiler_options",
    "env_sizes",
    "new_phase",
    "pace",
    "pace_metrics",
    "pacing_start",
    "phase_bodies",
    "phase_body",
    "phase_of_generation",
    "reevaluate",
    "run_start",
    "schedule_key",
    "scoring_function",
    "settle",
]
