"""Build a wheelhouse: every wheel smol-dsl needs on a machine without internet.

Run on a machine with internet (through `tools/wheelhouse.sh`, which documents the options);
the wheels are for the target's Python version and platform, not this machine's. With
`--missing-from FILE` (the target's `pip freeze`, or a requirements file), the packages the
target already has are left out, and their pinned versions constrain the rest, so that the
wheels fit what is installed there (its CUDA build of JAX above all). Without it, the
project's tested constraints file for that Python line pins the set.

What it does: builds smol-dsl's own wheel from this checkout; resolves smol-dsl and its
dependencies for the target with pip's resolver (`pip install --dry-run --report`, which
reads metadata only); downloads the wheels of the resolved set that the target lacks
(`pip download --no-deps`); copies `benchmarks/accelerator.py` beside them (the acceptance
command, README "On an offline GPU node"); writes `requirements.txt` (what is in the
wheelhouse, pinned) and prints every wheel with its size and the total.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ACCEPTANCE = ROOT / "benchmarks" / "accelerator.py"
PROJECT = "smol-dsl"
DEFAULT_GLIBC = "2.28"  # RHEL 8 and its rebuilds, common on clusters; newer systems take these too


class WheelhouseError(Exception):
    """A wheelhouse that cannot be built as asked, in words for the command line."""


def normalized(name: str) -> str:
    """A distribution name as pip compares them (PEP 503)."""
    return re.sub(r"[-_.]+", "-", name).lower()


@dataclass(frozen=True)
class Installed:
    """What a target environment has, read from its `pip freeze` or requirements file: the
    names present, and the versions pinned with `==`."""

    names: frozenset[str]
    pins: dict[str, str]


REQUIREMENT = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)\s*(\[[^\]]*\])?\s*(.*)$")


def read_installed(text: str, source: str = "the file") -> Installed:
    """The packages in a `pip freeze` output or requirements file: `name==version`, `name @
    URL`, `name>=...` and bare names; comments, blank lines and pip options (`-e`, `-r`,
    `--index-url`, ...) are skipped. A line that is none of these is an error naming it."""
    names: set[str] = set()
    pins: dict[str, str] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split(" #", 1)[0].strip()
        if not line or line.startswith(("#", "-")):
            continue
        match = REQUIREMENT.match(line)
        if match is None:
            raise WheelhouseError(
                f"{source}, line {number}: {raw.strip()!r} is not a requirement; "
                "hint: give the target's `pip freeze` output or a requirements file"
            )
        name, _, rest = match.groups()
        names.add(normalized(name))
        rest = rest.split(";", 1)[0].strip()
        if rest.startswith("==") and "," not in rest and "*" not in rest:
            pins[normalized(name)] = rest[2:].strip()
    return Installed(frozenset(names), pins)


def manylinux_platforms(arch: str, glibc: str) -> list[str]:
    """Every manylinux tag a Linux with this glibc and architecture installs (pip matches a
    `--platform` tag exactly, so each must be named): manylinux_2_17 up to the glibc, and the
    legacy aliases manylinux2014 (2.17), manylinux2010 (2.12) and manylinux1 (2.5) on x86."""
    try:
        major, minor = (int(part) for part in glibc.split("."))
    except ValueError:
        raise WheelhouseError(f"--glibc {glibc!r} is not a version; hint: e.g. --glibc 2.28") from None
    if major != 2 or minor < 17:
        raise WheelhouseError(f"--glibc {glibc}: manylinux wheels need glibc 2.17 or newer; hint: e.g. --glibc 2.28")
    tags = [f"manylinux_2_{m}_{arch}" for m in range(minor, 16, -1)]
    tags.append(f"manylinux2014_{arch}")
    if arch in ("x86_64", "i686"):
        tags += [f"manylinux2010_{arch}", f"manylinux1_{arch}"]
    return tags


def constraints_text(python_version: str, installed: Installed | None) -> str:
    """The constraints of the resolution: the target's pins where it has any, and the
    project's tested pins for this Python line for every other package."""
    pins: dict[str, str] = {}
    tested = ROOT / "constraints" / ("py3.11.txt" if python_version == "3.11" else "py3.12-3.13.txt")
    if tested.exists():
        tested_pins = read_installed(tested.read_text(), str(tested)).pins
        pins.update(tested_pins)
    if installed is not None:
        for name in list(pins):
            if name in installed.names:
                del pins[name]  # the target's own version (pinned below where it is known)
        pins.update(installed.pins)
    pins.pop(PROJECT, None)
    return "".join(f"{name}=={version}\n" for name, version in sorted(pins.items()))


def run_pip(pip: list[str], arguments: list[str], doing: str) -> None:
    """Run pip; a failure is a WheelhouseError with pip's last lines."""
    result = subprocess.run([*pip, *arguments], capture_output=True, text=True)
    if result.returncode != 0:
        tail = "\n".join((result.stderr or result.stdout).strip().splitlines()[-12:])
        raise WheelhouseError(f"{doing} failed (pip exit {result.returncode}):\n{tail}")


def target_options(python_version: str, platforms: list[str]) -> list[str]:
    """pip's options that select wheels for the target instead of this machine."""
    options = ["--only-binary=:all:", "--python-version", python_version, "--implementation", "cp"]
    for platform in platforms:
        options += ["--platform", platform]
    return options


LEAST_PIP = (24, 3)
"""Older pips check a wheel's dependencies against the running Python, not `--python-version`
("Package 'jax' requires a different Python"); measured: 23.2 and 24.0 fail, 24.3 works."""


def check_pip(pip: list[str]) -> None:
    """A WheelhouseError, with the upgrade to run, if this pip cannot resolve for another Python."""
    result = subprocess.run([*pip, "--version"], capture_output=True, text=True)
    match = re.match(r"pip (\d+)\.(\d+)", result.stdout)
    if match is None:
        raise WheelhouseError(f"no pip in {pip[0]}; hint: {pip[0]} -m ensurepip, or set PYTHON to another Python")
    version = (int(match.group(1)), int(match.group(2)))
    if version < LEAST_PIP:
        raise WheelhouseError(
            f"pip {version[0]}.{version[1]} ({pip[0]}) resolves for the Python it runs on, not the target's; "
            f"hint: {pip[0]} -m pip install -U 'pip>={LEAST_PIP[0]}.{LEAST_PIP[1]}', "
            "or set PYTHON to a Python with a newer pip"
        )


def build(
    python_version: str,
    out: Path,
    platforms: list[str],
    installed: Installed | None,
    extras: list[str],
    pip: list[str],
) -> list[Path]:
    """Fill `out` with the wheels (see the module's docstring); the wheels written."""
    check_pip(pip)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="wheelhouse-") as scratch:
        work = Path(scratch)
        own_wheel = ["wheel", "--no-deps", "--quiet", "--wheel-dir", str(work / "own"), str(ROOT)]
        run_pip(pip, own_wheel, "building smol-dsl's wheel")
        (own,) = (work / "own").glob("*.whl")
        shutil.copy2(own, out / own.name)
        constraints = work / "constraints.txt"
        constraints.write_text(constraints_text(python_version, installed))
        report = work / "report.json"
        wanted = f"{PROJECT}[{','.join(extras)}] @ {own.as_uri()}" if extras else f"{PROJECT} @ {own.as_uri()}"
        run_pip(
            pip,
            [
                *("install", "--dry-run", "--ignore-installed", "--quiet", "--report", str(report)),
                *("--target", str(work / "target"), "-c", str(constraints)),
                *target_options(python_version, platforms),
                wanted,
            ],
            f"resolving smol-dsl's dependencies for Python {python_version} on {platforms[0]}",
        )
        resolved = {
            normalized(item["metadata"]["name"]): item["metadata"]["version"]
            for item in json.loads(report.read_text())["install"]
        }
    resolved.pop(PROJECT, None)
    missing = sorted(name for name in resolved if installed is None or name not in installed.names)
    if missing:
        run_pip(
            pip,
            ["download", "--no-deps", "--quiet", "--dest", str(out)]
            + target_options(python_version, platforms)
            + [f"{name}=={resolved[name]}" for name in missing],
            "downloading the wheels",
        )
    shutil.copy2(ACCEPTANCE, out / ACCEPTANCE.name)
    pinned = [f"{PROJECT}=={own.name.split('-')[1]}"] + [f"{name}=={resolved[name]}" for name in missing]
    (out / "requirements.txt").write_text("\n".join(pinned) + "\n")
    return sorted(out.glob("*.whl"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="tools/wheelhouse.sh",
        description="Download every wheel smol-dsl needs for another machine's Python and platform (or only those "
        "it lacks), plus smol-dsl's own wheel, into one folder to carry to a machine without internet.",
    )
    parser.add_argument("--python-version", required=True, help="the target's Python, e.g. 3.12")
    parser.add_argument("--out", required=True, type=Path, help="the wheelhouse folder (created)")
    parser.add_argument(
        "--missing-from",
        type=Path,
        metavar="FILE",
        help="the target's `pip freeze` output (or a requirements file): leave out what it has, keep its versions",
    )
    parser.add_argument("--arch", default="x86_64", help="the target's machine, as `uname -m` prints it (x86_64)")
    parser.add_argument("--glibc", default=DEFAULT_GLIBC, help=f"the target's glibc, `ldd --version` ({DEFAULT_GLIBC})")
    parser.add_argument(
        "--platform",
        action="append",
        help="pip platform tags to take instead of the manylinux ones from --arch and --glibc (repeatable)",
    )
    parser.add_argument("--extras", default="", help="smol-dsl's extras to include, e.g. video or test,video")
    args = parser.parse_args(argv)
    try:
        if not re.fullmatch(r"3\.\d+", args.python_version):
            raise WheelhouseError(
                f"--python-version {args.python_version!r}: give major.minor; hint: --python-version 3.12"
            )
        installed = None
        if args.missing_from is not None:
            try:
                text = args.missing_from.read_text()
            except OSError as error:
                raise WheelhouseError(
                    f"--missing-from {args.missing_from}: {error.strerror}; hint: on the target, "
                    "`python -m pip freeze > freeze.txt`"
                ) from None
            installed = read_installed(text, str(args.missing_from))
        platforms = args.platform or manylinux_platforms(args.arch, args.glibc)
        extras = [extra.strip() for extra in args.extras.split(",") if extra.strip()]
        wheels = build(args.python_version, args.out, platforms, installed, extras, [sys.executable, "-m", "pip"])
    except WheelhouseError as error:
        print(f"tools/wheelhouse.sh: error: {error}", file=sys.stderr)
        return 2
    total = 0
    for wheel in wheels:
        size = wheel.stat().st_size
        total += size
        print(f"{size / 1e6:8.1f} MB  {wheel.name}")
    what = "missing from " + str(args.missing_from) if installed is not None else "all of smol-dsl's"
    print(
        f"{len(wheels)} wheels ({what}), {total / 1e6:.1f} MB in all, for Python {args.python_version} on "
        f"{platforms[0]}: {args.out}\n"
        f"install there: python{args.python_version} -m pip install --no-index --find-links {args.out} smol-dsl"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
