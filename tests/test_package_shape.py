"""The package's shape, as the runner's design promises it: modules small enough to read
(none over 450 lines), the run directory package the only writer that replaces files,
each step of the algorithm written once (CVT centroids), each condition's name spelled once."""

from __future__ import annotations

import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "smol_dsl"
MOST_LINES = 450
SOURCES = sorted(PACKAGE.rglob("*.py"))
DATA = sorted(p for p in PACKAGE.rglob("*") if p.is_file() and p.suffix in {".py", ".json", ".sched", ".toml"})


def relative(path: Path) -> str:
    return str(path.relative_to(PACKAGE.parent))


def occurrences(pattern: str, files: list[Path]) -> list[str]:
    """`file:line` of every line of `files` that matches `pattern`."""
    found = []
    for path in files:
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if re.search(pattern, line):
                found.append(f"{relative(path)}:{number}")
    return found


def test_no_module_is_over_450_lines():
    long = {relative(p): n for p in SOURCES if (n := len(p.read_text(encoding="utf-8").splitlines())) > MOST_LINES}
    assert not long, f"split these by concept: {long}"


def test_only_the_run_directory_package_replaces_files():
    assert {place.split(":")[0] for place in occurrences(r"os\.replace\(", SOURCES)} == {"smol_dsl/rundir/files.py"}


def test_cvt_centroids_are_computed_in_one_place():
    assert len(occurrences(r"compute_cvt_centroids\(", SOURCES)) == 1


def test_a_condition_s_display_name_is_spelled_once():
    assert len(occurrences(r"Extinction 5%", DATA)) == 1
