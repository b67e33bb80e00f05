"""smol-dsl: developmental curricula (actuator-scaling schedules) for quality-diversity robotics.

>>> import smol_dsl
>>> human = smol_dsl.load("human")          # the bundled SMOL-Human curriculum
>>> alphas = human.phase_alphas(100, key=None)  # alpha for each of 100 phases
>>> smol_dsl.load("growth").channels  # a schedule of several channels (physical parameters)
(Channel(kind='mass', targets=()), Channel(kind='gear', targets=()))
"""

from smol_dsl.errors import ScheduleError, UserInputError
from smol_dsl.language.channels import GEAR, BodyPlan, Channel
from smol_dsl.language.curve import Curve
from smol_dsl.language.library import library_names
from smol_dsl.language.schedule import Schedule, load, parse
from smol_dsl.language.verify import Certificate

__version__ = "0.1.0"

__all__ = [
    "GEAR",
    "BodyPlan",
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
