"""Summarise a compile profile (sitecustomize.py beside this file): the seconds of XLA
compilation, tracing and lowering per test file, the large compilations one by one (the
programs a test builds; two tests that build the same program on a cold cache, or the same
task at two sizes, show here), and the cache hits.

    python tools/compile_profile/report.py OUT [--large SECONDS] [--files N]
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path


def load(folder: Path) -> list[dict]:
    return [json.loads(line) for path in sorted(folder.glob("*.jsonl")) for line in path.open() if line.strip()]


def test_file(row: dict) -> str:
    return row["test"].split("::")[0] or "(outside a test)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--large", type=float, default=1.0, help="a compilation this long is listed (seconds)")
    parser.add_argument("--files", type=int, default=30, help="how many test files to list")
    args = parser.parse_args()
    rows = load(args.folder)
    totals: dict[str, float] = defaultdict(float)
    for row in rows:
        totals[row["kind"]] += row["seconds"]
    counts = defaultdict(int)
    for row in rows:
        counts[row["kind"]] += 1
    kinds = ("compile", "trace", "lower", "hit")
    print("all:", ", ".join(f"{kind} {totals[kind]:.0f} s ({counts[kind]})" for kind in kinds))

    by_file: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))
    for row in rows:
        by_file[test_file(row)][row["kind"]] += row["seconds"]
    print("\nseconds per test file:  compile   trace   lower")
    ranked = sorted(by_file.items(), key=lambda item: -sum(item[1].values()))
    for name, kinds in ranked[: args.files]:
        print(f"  {kinds['compile']:7.1f} {kinds['trace']:7.1f} {kinds['lower']:7.1f}  {name}")

    print(f"\ncompilations of {args.large:g} s or more (a subprocess is marked with its command):")
    large = [row for row in rows if row["kind"] == "compile" and row["seconds"] >= args.large]
    for row in sorted(large, key=lambda row: row["test"]):
        where = row["test"].replace("tests/", "")[:90]
        worker = row["command"] == "-c" or "pytest" in row["command"]  # pytest, or one of its xdist workers
        command = "" if worker else f"  [{row['command']}]"
        print(f"  {row['seconds']:5.1f} {row['function'][:28]:28s} {where}{command}")
    print(f"\n{len(large)} large compilations, {sum(row['seconds'] for row in large):.0f} s")


if __name__ == "__main__":
    main()
