"""A non-editable install ships the grammar, the schedule library and the commit it was built
from inside the package."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
LIBRARY = sorted(path.stem for path in (REPO / "schedules").glob("*.sched"))  # the checkout's library

PROBE = """
import smol_dsl, smol_dsl.runner, smol_dsl.tasks  # brax, mujoco and MJX too
from smol_dsl.language import grammar, library
assert smol_dsl.runner.__file__.startswith({site!r}) and smol_dsl.tasks.__file__.startswith({site!r})
assert str(grammar.GRAMMAR_FILE).startswith({site!r}), grammar.GRAMMAR_FILE
assert str(library.library_dir()).startswith({site!r}), library.library_dir()
assert smol_dsl.library_names() == {library!r}, smol_dsl.library_names()
print(smol_dsl.load("human").name, float(smol_dsl.load("smol").phase_alphas(100)[90]))
print(smol_dsl.load("growth").channels[0].name)
from smol_dsl.rundir import describe_environment
print(describe_environment([])["commit"])
"""


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    site = tmp_path_factory.mktemp("site")
    result = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target", str(site), str(REPO)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    if result.returncode != 0:
        pytest.fail(f"pip install failed:\n{result.stdout}\n{result.stderr}")
    return site


@pytest.mark.slow  # builds and installs the package
def test_installed_package_works_from_any_directory(installed, tmp_path):
    package = installed / "smol_dsl"
    assert (package / "language" / "sched.lark").is_file()
    assert sorted(path.stem for path in (package / "schedules").glob("*.sched")) == LIBRARY
    assert len(LIBRARY) == 13  # the paper's 8, growth, leg-damage, low-gravity, smol-paced and human-paced
    env = {**os.environ, "PYTHONPATH": str(installed)}
    result = subprocess.run(
        [sys.executable, "-c", PROBE.format(site=str(installed), library=LIBRARY)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    *printed, commit = result.stdout.split()
    assert printed == ["SMOL-Human", "1.0", "mass"]  # and nothing else: no MJX Warp lines
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    assert commit.removesuffix("+changes") == head  # the commit it was built from, for environment.json
