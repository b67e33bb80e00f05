"""QDax 0.5's gradient emitters (PGA-ME, DCRL-ME, QDPG, PBT-ME), importable with Brax v2.

Those modules import `QDEnv` from `qdax.tasks.brax.v1.envs.base_env` for one annotation
(the type of their `env` argument), and that package imports `brax.v1`, which Brax removed
in 0.10: with the Brax smol-dsl runs on (0.14), `import qdax.core.emitters.pga_me_emitter`
fails. Where `brax.v1` is missing, `install` registers a stand-in for that one module: its
`QDEnv` is the interface those emitters read (`observation_size`, `action_size`,
`state_descriptor_length`: what `smol_dsl.qdax.env_sizes` gives). Nothing else of QDax's
Brax v1 tasks is provided; where `brax.v1` exists, nothing is changed.
"""

from __future__ import annotations

import importlib.util
import sys
import types
from abc import ABC, abstractmethod

STAND_IN = "qdax.tasks.brax.v1.envs.base_env"


class QDEnv(ABC):
    """What QDax's gradient emitters read of their `env` (annotation only in QDax)."""

    @property
    @abstractmethod
    def observation_size(self) -> int: ...

    @property
    @abstractmethod
    def action_size(self) -> int: ...

    @property
    @abstractmethod
    def state_descriptor_length(self) -> int: ...


def brax_v1_missing() -> bool:
    try:
        return importlib.util.find_spec("brax.v1") is None
    except ModuleNotFoundError:  # no brax at all
        return True


def install() -> None:
    """Register the stand-in module where `brax.v1` is missing (once; idempotent)."""
    if STAND_IN in sys.modules or not brax_v1_missing():
        return
    module = types.ModuleType(STAND_IN, __doc__)
    module.QDEnv = QDEnv
    sys.modules[STAND_IN] = module
