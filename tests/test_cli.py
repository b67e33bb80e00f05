"""The `smol-dsl` command line: check, plot, help, version, bad input, and the wording of the
library's errors in the command line's options."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import smol_dsl
from smol_dsl.cli import OPTIONS, build_parser, main
from smol_dsl.errors import Message, Setting, UserInputError
from smol_dsl.runner import RunError, check_config, preset_config
from smol_dsl.runner.config import ConfigError
from smol_dsl.runner.directories import prepare_run_directory

BROKEN = 'name "broken"\n0% .. 40%: linear 1 -> 2\n50% .. 100%: tail\n'


def _command() -> list[str]:
    exe = shutil.which("smol-dsl")
    return [exe] if exe else [sys.executable, "-m", "smol_dsl.cli"]


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*_command(), *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_check_bundled_schedules_from_any_directory(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["check", *smol_dsl.library_names()]) == 0
    out = capsys.readouterr().out
    assert out.count(": ok: ") == len(smol_dsl.library_names())
    assert "tail: alpha == 1 from 90% to 100%" in out
    assert "bell to peak" in out and "increasing" in out


def test_check_reports_each_broken_file_and_exits_2(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    Path("broken.sched").write_text(BROKEN)
    assert main(["check", "smol", "broken.sched", "missing.sched"]) == 2
    captured = capsys.readouterr()
    assert ": ok: SMOL" in captured.out
    assert "broken.sched:3:1: error: gap between 40% and 50%" in captured.err
    assert "^^^" in captured.err and "hint:" in captured.err
    assert "missing.sched: error: no such file" in captured.err
    assert "Traceback" not in captured.err


def test_check_quiet(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["check", "-q", "human"]) == 0
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize("suffix", [".png", ".svg", ".pdf"])
def test_plot_writes_each_format(tmp_path, monkeypatch, capsys, suffix):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / f"fig{suffix}"
    assert main(["plot", "human", "smol", "random", "-o", str(out), "--phases", "20"]) == 0
    data = out.read_bytes()
    magic = {".png": b"\x89PNG", ".svg": b"<?xml", ".pdf": b"%PDF"}[suffix]
    assert data.startswith(magic)
    assert len(data) > 5000
    assert "SMOL-Human" in capsys.readouterr().out


def test_plot_defaults(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["plot"]) == 0
    assert (tmp_path / "schedules.png").is_file()
    assert main(["plot", "human.sched"]) == 0
    assert (tmp_path / "human.png").is_file()


def test_plot_bad_output(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["plot", "human", "-o", "fig.jpeg"]) == 2
    assert "one of .png, .svg, .pdf" in capsys.readouterr().err
    assert main(["plot", "human", "-o", "no/such/dir/fig.png"]) == 2
    assert "no such directory" in capsys.readouterr().err


def test_plot_broken_schedule(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    Path("broken.sched").write_text(BROKEN)
    assert main(["plot", "broken.sched"]) == 2
    assert "gap between" in capsys.readouterr().err
    assert not (tmp_path / "broken.png").exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["--no-such-flag"],
        ["check"],
        ["check", "human", "--frobnicate"],
        ["plot", "--phases", "0"],
        ["plot", "--phases", "many"],
        ["plot", "--seed", "x"],
        ["fly"],
        [],
    ],
)
def test_bad_flags_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as caught:
        main(argv)
    assert caught.value.code == 2
    err = capsys.readouterr().err
    assert "usage:" in err and "error:" in err


def test_help_and_version(capsys):
    for argv in (["--help"], ["check", "--help"], ["plot", "--help"]):
        with pytest.raises(SystemExit) as caught:
            main(argv)
        assert caught.value.code == 0
    out = capsys.readouterr().out
    assert "symbolically" in out and "Figure 2" in out
    assert "Bundled schedules: extinction-05" in out
    assert build_parser().epilog.endswith(f"Bundled schedules: {', '.join(smol_dsl.library_names())}.")
    with pytest.raises(SystemExit):
        main(["--version"])
    assert smol_dsl.__version__ in capsys.readouterr().out


def test_console_script_end_to_end(tmp_path):
    """The installed entry point: exit statuses and no traceback, from a clean directory."""
    (tmp_path / "broken.sched").write_text(BROKEN)
    ok = run_cli("check", "human.sched", cwd=tmp_path)
    assert ok.returncode == 0, ok.stderr
    assert "SMOL-Human" in ok.stdout
    bad = run_cli("check", "broken.sched", cwd=tmp_path)
    assert bad.returncode == 2
    assert "broken.sched:3:1: error:" in bad.stderr and "Traceback" not in bad.stderr
    flag = run_cli("plot", "--bogus", cwd=tmp_path)
    assert flag.returncode == 2 and "Traceback" not in flag.stderr
    junk = tmp_path / "junk.sched"
    junk.write_bytes(bytes(range(256)))
    binary = run_cli("check", str(junk), cwd=tmp_path)
    assert binary.returncode == 2 and "Traceback" not in binary.stderr


def test_plot_notes_phase_counts_without_an_alpha_one_phase(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["plot", "smol", "--phases", "7"]) == 0
    assert "no phase of SMOL runs wholly at alpha = 1" in capsys.readouterr().err


def test_each_command_parses_its_own_options():
    parser = build_parser()
    run = parser.parse_args(["run", "walker2d", "human", "--seed", "3", "--phases", "12"])
    sweep = parser.parse_args(["sweep", "walker2d", "human", "smol", "--seeds", "2", "--runs-per-step", "4"])
    assert (run.command, run.schedules, run.seed, run.phases) == ("run", ["human"], 3, 12)
    assert (sweep.command, sweep.schedules, sweep.seeds, sweep.runs_per_step) == ("sweep", ["human", "smol"], 2, 4)
    # what a run has no option for is a sweep's default: one process, runs per step chosen by the devices
    assert (run.num_processes, run.process_id, run.cluster, run.runs_per_step) == (None, None, False, None)
    assert sweep.seed is None  # a sweep's shared settings carry no seed
    assert parser.parse_args(["report", "d", "--metric", "coverage"]).metric == "coverage"
    with pytest.raises(SystemExit):
        parser.parse_args(["run", "walker2d", "human", "--seeds", "2"])  # sweep's option, not run's


def test_a_message_names_a_setting_by_its_name_or_as_told():
    message = "use " + Setting("evaluations") + " 10 or more, fewer " + Setting("num_phases")
    assert isinstance(message, Message)
    assert str(message) == "use evaluations 10 or more, fewer num_phases"
    assert message.worded({"evaluations": "--evals"}) == "use --evals 10 or more, fewer num_phases"
    assert str(Message.joined("; ", ["a", Setting("b"), "c" + Setting("d")])) == "a; b; cd"
    error = UserInputError(message)
    assert str(error) == str(message) and error.worded(OPTIONS) == "use --evals 10 or more, fewer --phases"
    assert UserInputError("plain text").worded(OPTIONS) == "plain text"
    # a RunConfig field without an option of its own is the preset's
    assert (Setting("hidden_layer_sizes") + "").worded(OPTIONS) == "hidden_layer_sizes (set by --preset)"


def test_the_library_names_settings_and_the_command_line_its_options(library, tmp_path, monkeypatch, capsys):
    """check_config and a refused resume name RunConfig's fields in Python; `smol-dsl run` says
    the same with its options, word for word as its users know them."""
    with pytest.raises(ConfigError) as caught:
        check_config(preset_config("walker2d", num_phases=5), library["human"])
    assert isinstance(caught.value, ValueError) and isinstance(caught.value, RunError)
    assert str(caught.value).endswith("so the run would not end on its final body; use num_phases 10 or more")
    assert caught.value.worded(OPTIONS).endswith("; use --phases 10 or more")
    with pytest.raises(ConfigError, match=r"use evaluations 2688 or more, fewer num_phases, or a smaller batch_size$"):
        check_config(preset_config("walker2d", evaluations=100), library["human"])
    with pytest.raises(ConfigError, match=r"^num_centroids must be at least 2, not 1$"):
        check_config(preset_config("walker2d", num_centroids=1), library["human"])

    small = dict(evaluations=96, batch_size=8, num_phases=10, num_centroids=16, episode_length=10)
    out = tmp_path / "run"
    prepare_run_directory(out, library["human"], preset_config("walker2d", **small), resume=False).release()
    with pytest.raises(RunError) as caught:
        prepare_run_directory(
            out, library["human"], preset_config("walker2d", **{**small, "batch_size": 16}), resume=True
        )
    assert str(caught.value).endswith("resume it with the same ones: batch_size: the run was started with 8, not 16")
    assert caught.value.worded(OPTIONS).endswith(": --batch-size: the run was started with 8, not 16")

    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))  # `run` sets it; restored after the test
    assert main(["run", "walker2d", "human", "--phases", "5", "--out", str(tmp_path / "new")]) == 2
    assert capsys.readouterr().err == (
        "smol-dsl run: error: with 5 phases no phase lies wholly in the final-body tail of SMOL-Human (from 90%), "
        "so the run would not end on its final body; use --phases 10 or more\n"
    )
    assert main(["run", "walker2d", "human", "--evals", "100", "--out", str(tmp_path / "new")]) == 2
    assert capsys.readouterr().err.endswith("; use --evals 2688 or more, fewer --phases, or a smaller --batch-size\n")
    assert not (tmp_path / "new").exists()


def test_a_dry_run_refuses_the_sweeps_that_training_would(tmp_path, capsys):
    """--dry-run answers as the sweep would, before anything is sized or compiled."""
    for folder, factor in (("a", "1.2"), ("b", "1.3")):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "mine.sched").write_text(f"0% .. 90%: constant {factor}\n90% .. 100%: tail\n")
    for schedules in (["vanilla", "vanilla"], [str(tmp_path / "a" / "mine.sched"), str(tmp_path / "b" / "mine.sched")]):
        code = main(["sweep", "walker2d", *schedules, "--dry-run", "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert code == 2 and "two runs of the sweep would share the directory" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()
