"""An emitter's state at a phase boundary: what of it depends on the body, brought up to date.

At a boundary the repertoire is re-scored into a fresh one (`reevaluate`), and two kinds of
emitter state describe the old body:

- `previous_fitnesses` (QDax's CMA emitters: improvement, optimizing, random direction,
  their pools; CMA-MEGA): the repertoire's fitnesses as of the last `tell`, against which
  offspring are ranked by improvement. Left alone, every offspring of a weaker body would
  rank as a loss against fitnesses the new body cannot reach. `new_phase` sets them to the
  fresh repertoire's, as the emitter's own `state_update` would have. The search
  distribution (mean, covariance, step size) is kept: it describes where in parameter space
  good policies lie, which a small change of the body does not move.
- replay buffers (PGA-ME's and DCRL-ME's critic training; `ReplayBuffer` anywhere in the
  state): transitions simulated in the old body. They are kept by default: a schedule moves
  the body a little each phase, the critic learns from them as from any off-policy data,
  and emptying the buffer every phase (the paper has 100) would leave the critic too few
  transitions to learn from; `replay="clear"` empties them for an abrupt change of body.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, Literal

import jax.numpy as jnp

if TYPE_CHECKING:
    from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire


def new_phase(emitter_state: Any, repertoire: MapElitesRepertoire, *, replay: Literal["keep", "clear"] = "keep") -> Any:
    """`emitter_state` for the next phase, given the freshly re-evaluated `repertoire`:
    every `previous_fitnesses` set to the repertoire's fitnesses, every replay buffer kept
    (or emptied with `replay="clear"`); every other part unchanged. Any QDax emitter state,
    nested in multi-emitter or pool states; None (emitters without state) stays None."""
    if replay not in ("keep", "clear"):
        raise ValueError(f"replay {replay!r}: 'keep' the transitions of the old body, or 'clear' them")
    return _updated(emitter_state, repertoire.fitnesses, replay == "clear")


def _updated(node: Any, fitnesses: Any, clear: bool) -> Any:
    from qdax.core.neuroevolution.buffers.buffer import ReplayBuffer

    if isinstance(node, ReplayBuffer):
        if not clear:
            return node
        zero = jnp.zeros_like(node.current_size)
        return node.replace(current_position=jnp.zeros_like(node.current_position), current_size=zero)
    if isinstance(node, (tuple, list)):
        items = [_updated(item, fitnesses, clear) for item in node]
        if all(new is old for new, old in zip(items, node, strict=True)):
            return node
        return type(node)(*items) if hasattr(node, "_fields") else type(node)(items)  # named tuples too
    if isinstance(node, dict):
        updated = {name: _updated(item, fitnesses, clear) for name, item in node.items()}
        return node if all(updated[name] is node[name] for name in node) else updated
    if dataclasses.is_dataclass(node) and not isinstance(node, type):
        changes = {}
        for field in dataclasses.fields(node):
            value = getattr(node, field.name)
            if field.name == "previous_fitnesses" and value is not None:
                changes[field.name] = jnp.broadcast_to(fitnesses, jnp.shape(value))  # pools stack one per emitter
            else:
                updated = _updated(value, fitnesses, clear)
                if updated is not value:
                    changes[field.name] = updated
        return node.replace(**changes) if changes else node
    return node
