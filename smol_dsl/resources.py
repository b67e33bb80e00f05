"""Where the grammar and the bundled schedule library live, installed or in a checkout."""

from __future__ import annotations

from pathlib import Path

_CHECKOUT = Path(__file__).resolve().parent.parent


def _package_dir(package: str, checkout_dir: str) -> Path:
    # Installed (editable or not), setuptools maps grammar/ and schedules/ to
    # smol_dsl.grammar and smol_dsl.schedules; running from a bare checkout, use the
    # top-level folders directly.
    here = Path(__file__).resolve().parent / package.rsplit(".", 1)[1]
    if here.is_dir():
        return here
    try:
        from importlib.resources import files

        found = Path(str(files(package)))
        if found.is_dir():
            return found
    except (ModuleNotFoundError, TypeError):
        pass
    return _CHECKOUT / checkout_dir


def grammar_path() -> Path:
    """The Lark grammar of the `.sched` language."""
    return _package_dir("smol_dsl.grammar", "grammar") / "sched.lark"


def library_dir() -> Path:
    """The folder of bundled `.sched` files (the paper's curricula)."""
    return _package_dir("smol_dsl.schedules", "schedules")


def library_names() -> list[str]:
    """Names of the bundled schedules, without the `.sched` suffix, sorted."""
    return sorted(p.stem for p in library_dir().glob("*.sched"))
