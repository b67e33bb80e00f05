"""Hashes of reference runs: what a refactoring of the runner must leave bit for bit.

Trains a fixed set of small runs and sweeps (the command line's `run` and `sweep`, and a
run interrupted and resumed through the Python API) into a scratch folder and prints one
line per file that holds results: the sha256 of each array of archive.npz (genotypes,
fitnesses, descriptors, centroids, filled, lanes) and of metrics.csv. Run it before and
after a change, on the same machine and software, and compare the two outputs (`diff`).

    python tools/reference_hashes.py [--out hashes.txt] [--keep DIR]
"""

from __future__ import annotations

import argparse
import hashlib
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

SMALL = ["--evals", "1408", "--batch-size", "64", "--phases", "10", "--centroids", "32", "--episode-length", "20"]
COMMANDS = {
    "walker2d-smol": ["run", "walker2d", "smol", *SMALL],
    "ant_omni-random-seed3": ["run", "ant_omni", "random", "--seed", "3", *SMALL],
    "hopper-extinction": ["run", "hopper", "extinction-50", *SMALL],
    "sweep-halfcheetah": ["sweep", "halfcheetah", "smol", "vanilla", "--seeds", "2", *SMALL],
}
RESUMED = "walker2d-human-resumed"
RESUME_SCRIPT = """
import sys
from smol_dsl.language.schedule import load
from smol_dsl.runner import preset_config, run_experiment
config = preset_config("walker2d", evaluations=1408, batch_size=64, num_phases=10, num_centroids=32, episode_length=20)
schedule = load("human")
run_experiment("walker2d", schedule, config, out_dir=sys.argv[1], stop_after_generation=9)
run_experiment("walker2d", schedule, config, out_dir=sys.argv[1], resume=True)
"""


def digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def run_hashes(name: str, directory: Path) -> list[str]:
    """One line per array of the run's archive.npz and one for its metrics.csv."""
    lines = []
    with np.load(directory / "archive.npz") as archive:
        for key in sorted(archive.files):
            array = np.ascontiguousarray(archive[key])
            lines.append(f"{name} archive:{key} {array.dtype} {array.shape} {digest(array.tobytes())}")
    lines.append(f"{name} metrics.csv {digest((directory / 'metrics.csv').read_bytes())}")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="also write the hashes to this file")
    parser.add_argument("--keep", type=Path, help="train into this folder and keep it (default: a temporary one)")
    args = parser.parse_args()
    scratch = args.keep or Path(tempfile.mkdtemp(prefix="smol-reference-"))
    lines: list[str] = []
    try:
        for name, command in COMMANDS.items():
            out = scratch / name
            subprocess.run(
                [sys.executable, "-m", "smol_dsl.cli", *command, "--out", str(out), "--no-progress"],
                check=True,
                stdout=subprocess.DEVNULL,
            )
            runs = sorted(path.parent for path in out.rglob("archive.npz"))
            for run in runs:
                lines += run_hashes(f"{name}/{run.relative_to(out)}" if run != out else name, run)
        subprocess.run([sys.executable, "-c", RESUME_SCRIPT, str(scratch / RESUMED)], check=True)
        lines += run_hashes(RESUMED, scratch / RESUMED)
    finally:
        if args.keep is None:
            shutil.rmtree(scratch, ignore_errors=True)
    text = "\n".join(lines) + "\n"
    sys.stdout.write(text)
    if args.out:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
