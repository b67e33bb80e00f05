"""Brax and MuJoCo, without the start-up noise a smol-dsl user cannot act on.

- MuJoCo 4's MJX prints ``Failed to import warp: ...`` (and ``mujoco_warp``) on stdout when
  it is first imported: Warp is an optional GPU backend that Brax's `spring` pipeline never
  uses.
- Brax warns (a UserWarning) at every model it loads that its pipelines are not actively
  maintained; smol-dsl uses them on purpose, as the paper did.
- MuJoCo's default warning handler writes model-compiler warnings (Brax's bundled
  halfcheetah uses a deprecated attribute) to the console and to ``MUJOCO_LOG.TXT`` in the
  current directory.

smol-dsl goes into those libraries only through `import_brax` and `brax_environment`, which
filter exactly these and nothing else, without changing the libraries: other output of the
import is passed on, and MuJoCo's warnings go to the ``smol_dsl.tasks`` logger while a model
is built (the previous handler is restored after).
"""

from __future__ import annotations

import contextlib
import io
import logging
import re
import sys
import warnings
from collections.abc import Iterator
from typing import Any

from smol_dsl.tasks.physics import check_mjx_implementation

WARP_LINE = re.compile(r"Failed to import (mujoco_)?warp: ")
BRAX_MAINTENANCE = r"Brax System, piplines and environments are not actively"  # sic, as Brax spells it

logger = logging.getLogger("smol_dsl.tasks")


def import_brax() -> None:
    """Import `brax.envs` (and with it MuJoCo MJX), dropping MJX's Warp import lines."""
    if "brax.envs" in sys.modules:
        return
    captured = io.StringIO()
    with contextlib.redirect_stdout(captured):
        import brax.envs  # noqa: F401
    for line in captured.getvalue().splitlines():
        if not WARP_LINE.match(line):
            print(line)


def _log_mujoco_warning(message: str) -> None:
    logger.info("MuJoCo: %s", message)


@contextlib.contextmanager
def building_models() -> Iterator[None]:
    """While Brax loads models: its maintenance warning filtered, MuJoCo's compiler
    warnings logged instead of printed and written to MUJOCO_LOG.TXT."""
    import mujoco

    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(_log_mujoco_warning)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=BRAX_MAINTENANCE, category=UserWarning)
            yield
    finally:
        mujoco.set_mju_user_warning(previous)


def brax_environment(name: str, **options: Any) -> Any:
    """`brax.envs.get_environment(name, **options)`, quietly; on MJX (`backend="mjx"`), one
    whose model MJX built for MJX-JAX (`physics.check_mjx_implementation`)."""
    import_brax()
    import brax.envs

    with building_models():
        env = brax.envs.get_environment(name, **options)
    if options.get("backend") == "mjx":
        check_mjx_implementation(env.sys.impl.value)
    return env
