"""tools/wheelhouse.sh: a wheelhouse for a machine without internet, installable with
`pip install --no-index` (README, "On an offline GPU node")."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SCRIPT = REPO / "tools" / "wheelhouse.sh"


def _load():
    spec = importlib.util.spec_from_file_location("wheelhouse", REPO / "tools" / "wheelhouse.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


wheelhouse = _load()


def test_a_freeze_gives_the_names_present_and_their_pins():
    installed = wheelhouse.read_installed(
        "# pip freeze\n"
        "jax==0.11.0\n"
        "Jax_CUDA13_Plugin==0.11.0\n"
        "numpy>=2  # a range, no pin\n"
        "smol-dsl @ file:///tmp/smol_dsl-0.1.0-py3-none-any.whl\n"
        "-e git+https://example.org/repo#egg=thing\n"
        "--index-url https://example.org/simple\n"
        "\n"
        "ml_collections==1.1.0 ; python_version >= '3.10'\n"
    )
    assert installed.names == {"jax", "jax-cuda13-plugin", "numpy", "smol-dsl", "ml-collections"}
    assert installed.pins == {"jax": "0.11.0", "jax-cuda13-plugin": "0.11.0", "ml-collections": "1.1.0"}


def test_a_line_that_is_no_requirement_is_named():
    with pytest.raises(wheelhouse.WheelhouseError, match=r"freeze.txt, line 2: '== 1.0' is not a requirement"):
        wheelhouse.read_installed("jax==0.11.0\n== 1.0\n", "freeze.txt")


def test_the_target_s_pins_replace_the_tested_ones():
    """The target's JAX stays what it is; what it lacks keeps the tested versions."""
    installed = wheelhouse.read_installed("jax==0.11.0\njaxlib==0.11.0\nscipy\n")
    constraints = dict(line.split("==") for line in wheelhouse.constraints_text("3.12", installed).splitlines())
    assert constraints["jax"] == "0.11.0" and constraints["jaxlib"] == "0.11.0"
    assert "scipy" not in constraints  # present there, unpinned: its own version
    assert constraints["brax"] == "0.14.2" and "smol-dsl" not in constraints
    assert wheelhouse.constraints_text("3.11", None).count("jax==0.10.2") == 1


def test_platforms_name_every_manylinux_tag_up_to_the_glibc():
    tags = wheelhouse.manylinux_platforms("x86_64", "2.28")
    assert tags[0] == "manylinux_2_28_x86_64" and "manylinux_2_27_x86_64" in tags and "manylinux_2_17_x86_64" in tags
    assert tags[-3:] == ["manylinux2014_x86_64", "manylinux2010_x86_64", "manylinux1_x86_64"]
    assert wheelhouse.manylinux_platforms("aarch64", "2.17") == ["manylinux_2_17_aarch64", "manylinux2014_aarch64"]
    with pytest.raises(wheelhouse.WheelhouseError, match=r"glibc 2\.17 or newer"):
        wheelhouse.manylinux_platforms("x86_64", "2.12")


@pytest.mark.parametrize(
    ("arguments", "words"),
    [
        (["--python-version", "312", "--out", "w"], "--python-version '312': give major.minor"),
        (["--python-version", "3.12", "--out", "w", "--missing-from", "nothere.txt"], "pip freeze > freeze.txt"),
        (["--python-version", "3.12", "--out", "w", "--glibc", "two"], "--glibc 'two' is not a version"),
    ],
)
def test_bad_options_are_refused_before_any_download(tmp_path, arguments, words):
    result = subprocess.run(
        [str(SCRIPT), *arguments],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "PYTHON": sys.executable},
    )
    assert result.returncode == 2 and words in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "w").exists()


def test_an_old_pip_is_refused_with_the_upgrade_to_run():
    with pytest.raises(wheelhouse.WheelhouseError, match=r"pip 23.2 .* pip install -U 'pip>=24.3'"):
        wheelhouse.check_pip(["sh", "-c", "echo 'pip 23.2.1 from somewhere'", "--"])


@pytest.mark.slow
def test_a_wheelhouse_missing_from_this_environment_installs_offline_and_runs(tmp_path):
    """The wheels this environment lacks (lark and jax-tqdm, left out of its freeze) and
    smol-dsl's own, installed with --no-index beside it: `smol-dsl check` runs from them.
    Needs the package index (as the README's install does), and a pip that resolves for
    another Python (installed into a folder here if this one is older)."""
    freeze = subprocess.run(
        [sys.executable, "-m", "pip", "freeze", "--exclude-editable"], capture_output=True, text=True, check=True
    ).stdout
    kept = [line for line in freeze.splitlines() if not line.lower().startswith(("lark", "jax-tqdm", "jax_tqdm"))]
    (tmp_path / "freeze.txt").write_text("\n".join(kept) + "\n")
    env = {**os.environ, "PYTHON": sys.executable}
    try:
        wheelhouse.check_pip([sys.executable, "-m", "pip"])
    except wheelhouse.WheelhouseError:
        pip = tmp_path / "pip"
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--target", str(pip), "pip>=24.3"], check=True)
        env["PYTHONPATH"] = str(pip)
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    built = subprocess.run(
        [str(SCRIPT), "--python-version", version, "--out", "wheels", "--missing-from", "freeze.txt"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=env,
    )
    assert built.returncode == 0, built.stderr[-3000:]
    wheels = sorted(path.name.split("-")[0] for path in (tmp_path / "wheels").glob("*.whl"))
    assert wheels == ["jax_tqdm", "lark", "smol_dsl"]
    assert "3 wheels (missing from freeze.txt)" in built.stdout and " MB in all" in built.stdout
    assert (tmp_path / "wheels" / "accelerator.py").is_file()
    requirements = (tmp_path / "wheels" / "requirements.txt").read_text().split()
    assert requirements[0] == "smol-dsl==0.1.0" and any(line.startswith("lark==") for line in requirements)
    (own,) = (tmp_path / "wheels").glob("smol_dsl-*.whl")
    assert "smol_dsl/schedules/human.sched" in zipfile.ZipFile(own).namelist()

    target = tmp_path / "site"
    install = [sys.executable, "-m", "pip", "install", "-q", "--no-index", "--no-deps", "--target", str(target)]
    subprocess.run([*install, *map(str, (tmp_path / "wheels").glob("*.whl"))], check=True, cwd=tmp_path)
    checked = subprocess.run(
        [sys.executable, "-c", "import smol_dsl, lark; print(smol_dsl.__file__); print(lark.__file__)"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(target)},
    )
    assert checked.returncode == 0, checked.stderr
    assert all(line.startswith(str(target)) for line in checked.stdout.split())
    check = subprocess.run(
        [sys.executable, "-m", "smol_dsl.cli", "check", "human"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(target)},
    )
    assert check.returncode == 0 and "proven" in check.stdout, check.stdout + check.stderr
