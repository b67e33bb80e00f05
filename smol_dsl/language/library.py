"""Where the bundled schedule library (the paper's curricula) lives, installed or in a checkout."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parents[1]
_CHECKOUT = _PACKAGE.parent


def library_dir() -> Path:
    """The folder of bundled `.sched` files (the paper's curricula).

    setuptools maps the checkout's top-level `schedules/` folder to the package
    `smol_dsl.schedules`: a folder inside the package after a non-editable install, found
    through importlib after an editable one; from a bare checkout, the folder itself.
    """
    here = _PACKAGE / "schedules"
    if here.is_dir():
        return here
    try:
        found = Path(str(files("smol_dsl.schedules")))
        if found.is_dir():
            return found
    except (ModuleNotFoundError, TypeError):
        pass
    return _CHECKOUT / "schedules"


def library_names() -> list[str]:
    """Names of the bundled schedules, without the `.sched` suffix, sorted."""
    return sorted(p.stem for p in library_dir().glob("*.sched"))
