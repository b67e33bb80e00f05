"""The examples in the package's docstrings run and print what they show.

Every module of `smol_dsl` is imported and its `>>>` examples are run with `doctest`, one
test per module that has any; a module whose examples stop running fails here, and so does
the package if its examples disappear altogether.
"""

from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest

import smol_dsl

ENTRY_POINTS = {"smol_dsl.cli.__main__"}
"""Modules that act when imported (`python -m`): they hold no examples."""


def _modules_with_examples() -> list[str]:
    """The package's modules whose source holds a `>>>` line (read, not imported: collecting
    this file imports no JAX)."""
    root = Path(smol_dsl.__file__).parent
    names = []
    for path in sorted(root.rglob("*.py")):
        parts = ("smol_dsl", *path.relative_to(root).with_suffix("").parts)
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        if name not in ENTRY_POINTS and ">>>" in path.read_text(encoding="utf-8"):
            names.append(name)
    return names


def _examples(name: str) -> list[doctest.DocTest]:
    module = importlib.import_module(name)
    tests = doctest.DocTestFinder(exclude_empty=True).find(module, name)
    return [test for test in tests if test.examples]


MODULES_WITH_EXAMPLES = _modules_with_examples()


def test_the_package_has_examples_to_run():
    assert {"smol_dsl", "smol_dsl.language.schedule", "smol_dsl.language.curve"} <= set(MODULES_WITH_EXAMPLES)


@pytest.mark.parametrize("name", MODULES_WITH_EXAMPLES)
def test_docstring_examples_run(name):
    tests = _examples(name)
    assert tests, f"{name} has `>>>` lines but no docstring examples doctest can find"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in tests:
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.attempted > 0
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples in {name} failed (printed above)"
