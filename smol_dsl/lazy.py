"""Names of a package loaded from their modules on first use (PEP 562), so that importing the
package loads nothing heavy: one helper for every package that does it."""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping, Sequence
from importlib import import_module
from typing import Any


def lazy_names(
    package: str, modules: Mapping[str, str], public: Sequence[str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The `__getattr__` and `__dir__` of `package`: a name of `modules` (name: the module
    that defines it) is imported on first use and kept in the package, so later uses cost
    nothing; `dir()` lists `public` (the package's `__all__`)."""

    def load_on_first_use(name: str) -> Any:
        if name in modules:
            value = getattr(import_module(modules[name]), name)
            setattr(sys.modules[package], name, value)
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def listed() -> list[str]:
        return sorted(public)

    return load_on_first_use, listed
