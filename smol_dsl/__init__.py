"""smol-dsl: developmental curricula (schedules of the body) for quality-diversity robotics.

>>> import smol_dsl
>>> human = smol_dsl.load("human")          # the bundled SMOL-Human curriculum
>>> human.phase_alphas(100).shape           # alpha for each of 100 phases
(100,)
>>> smol_dsl.load("growth").channels  # a schedule of several channels (physical parameters)
(Channel(kind='mass', targets=()), Channel(kind='gear', targets=()))

Names are loaded on first use, so `import smol_dsl.rundir` (reading run directories) or
`import smol_dsl.tasks` loads neither sympy nor Lark nor JAX.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from smol_dsl.errors import ScheduleError, UserInputError
from smol_dsl.lazy import lazy_names

if TYPE_CHECKING:
    from smol_dsl.language.certificates import Certificate
    from smol_dsl.language.channels import GEAR, Channel
    from smol_dsl.language.curve import Curve
    from smol_dsl.language.library import library_names
    from smol_dsl.language.schedule import Schedule, load, parse
    from smol_dsl.tasks.anatomy import Anatomy

__version__ = "0.1.0"

_LAZY = {
    "GEAR": "smol_dsl.language.channels",
    "Channel": "smol_dsl.language.channels",
    "Curve": "smol_dsl.language.curve",
    "library_names": "smol_dsl.language.library",
    "Schedule": "smol_dsl.language.schedule",
    "load": "smol_dsl.language.schedule",
    "parse": "smol_dsl.language.schedule",
    "Certificate": "smol_dsl.language.certificates",
    "Anatomy": "smol_dsl.tasks.anatomy",
}

__all__ = [
    "GEAR",
    "Anatomy",
    "Certificate",
    "Channel",
    "Curve",
    "Schedule",
    "ScheduleError",
    "UserInputError",
    "__version__",
    "library_names",
    "load",
    "parse",
]

__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
