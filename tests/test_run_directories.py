"""Run and sweep directories (runner/directories.py, runner/lock.py): an --out that cannot be
one, refused before anything compiles; resumes refused with what differs or is damaged; one
process at a time per directory, and the processes of one sweep sharing its directory."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from small_runs import CONFIG, FLAGS, RUN, cli, copy_of

from smol_dsl.cli import OPTIONS
from smol_dsl.rundir.layout import sweep_checkpoint_file
from smol_dsl.runner import RunError, preset_config, run_experiment
from smol_dsl.runner.directories import prepare_sweep_directory
from smol_dsl.runner.lock import DirectoryLock
from smol_dsl.runner.sweep import plan_sweep


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_out_that_cannot_be_a_run_directory(command, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    Path("afile").write_text("precious")
    argv = RUN if command == "run" else ["sweep", "walker2d", "human", "--seeds", "1", *FLAGS, "--no-progress"]
    for out, message in (
        ("afile", "--out afile: afile is a file, not a directory"),
        ("/dev/null", "--out /dev/null: /dev/null is a special file"),
        ("afile/run", "--out afile/run: afile is a file, not a directory"),
        ("", "--out: empty path"),
        ("  ", "--out: empty path"),
    ):
        code, err = cli([*argv, "--out", out], capsys)
        assert code == 2, (out, err)
        assert message in err, err
    assert Path("afile").read_text() == "precious"
    assert sorted(os.listdir()) == ["afile"]  # nothing was created, not even runs/


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_out_is_refused_before_anything_compiles(command, tmp_path, monkeypatch, capsys):
    import smol_dsl.runner

    def never(*args, **kwargs):
        raise AssertionError("the runner started")

    monkeypatch.setattr(smol_dsl.runner, "run_experiment", never)
    monkeypatch.setattr(smol_dsl.runner, "run_sweep", never)
    monkeypatch.chdir(tmp_path)
    Path("afile").write_text("precious")
    Path("busy").mkdir()
    Path("busy/notes.txt").write_text("precious")
    argv = RUN if command == "run" else ["sweep", "walker2d", "human", "--seeds", "1", *FLAGS, "--no-progress"]
    for out, message in (
        ("afile", "afile is a file"),
        ("busy", "busy already exists and is not empty; use --resume"),
    ):
        code, err = cli([*argv, "--out", out], capsys)
        assert code == 2 and message in err, (out, err)
    assert Path("busy/notes.txt").read_text() == "precious"


def test_library_refuses_an_empty_out_dir(library):
    with pytest.raises(RunError, match="--out: empty path"):
        run_experiment("walker2d", library["human"], CONFIG, out_dir="")


@pytest.mark.parametrize(
    ("text", "problem"), [("{", "not JSON"), ("[1, 2]", "not a JSON object"), ("\xff\xfe", "not JSON")]
)
def test_resume_with_a_damaged_config_json(small_run, tmp_path, capsys, text, problem):
    out = copy_of(small_run, tmp_path)
    (out / "config.json").write_bytes(text.encode("latin-1"))
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2
    assert f"{out / 'config.json'} is damaged ({problem}" in err and "put back a good copy" in err


def test_resume_of_a_sweep_as_a_run_and_of_a_run_as_a_sweep(small_run, library, tmp_path, capsys):
    out = tmp_path / "sweep"
    every = plan_sweep([library["human"]], [0], CONFIG)
    prepare_sweep_directory(out, every, every, CONFIG, False, False, "sweep-checkpoint.npz").close()
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2 and f"{out} is a sweep directory, not a run's" in err
    code, err = cli(["sweep", "walker2d", "human", "--seeds", "1", *FLAGS, "--out", str(small_run), "--resume"], capsys)
    assert code == 2 and f"{small_run} is a run directory, not a sweep's" in err


def test_resume_without_its_schedule_file(small_run, tmp_path, capsys):
    out = copy_of(small_run, tmp_path)
    (out / "schedule.sched").unlink()
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2 and f"{out} holds no schedule.sched" in err


def test_resume_with_a_damaged_phases_file_is_refused_and_changes_nothing(small_run, tmp_path, capsys):
    """The phases trained so far are only in phases.npz (a checkpoint holds the latest archive):
    resuming would drop them unseen, so it is refused, naming the file and the way on."""
    out = copy_of(small_run, tmp_path)
    phases = out / "phases.npz"
    phases.write_bytes(phases.read_bytes()[:300])  # cut short: a full disk, an unfinished copy
    before = {path.name: path.read_bytes() for path in out.iterdir()}
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2 and f"{phases}: not a readable phases file" in err, err
    assert "remove the file to resume without them" in err and "rerun the run" in err, err
    assert {path.name: path.read_bytes() for path in out.iterdir()} == before


HOLD = """
import sys
from pathlib import Path
from smol_dsl.runner.lock import DirectoryLock
lock = DirectoryLock.acquire(Path(sys.argv[1]))
print("locked", flush=True)
sys.stdin.read()
"""


def test_a_second_process_on_a_run_directory_is_refused(small_run, tmp_path, capsys):
    out = copy_of(small_run, tmp_path)
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
        assert code == 2
        assert f"{out} is in use by another smol-dsl process (pid {holder.pid} on " in err
        assert "only one process at a time" in err
    finally:
        holder.stdin.close()
        holder.wait(timeout=60)
    with DirectoryLock.acquire(out) as lock:  # released when its holder exited
        assert lock.held


@pytest.mark.slow  # its sweep commands size Brax tasks before they are refused
def test_a_second_sweep_process_is_refused_but_parts_share_a_sweep(library, tmp_path, capsys):
    out = tmp_path / "sweep"
    schedules = [library["human"], library["smol"]]
    every = plan_sweep(schedules, [0, 1], CONFIG)

    def prepare(part, parts, resume=False):
        name = sweep_checkpoint_file((part, parts))
        return prepare_sweep_directory(out, every, every[part::parts], CONFIG, resume, parts > 1, name)

    with prepare(0, 2), prepare(1, 2):  # two processes of one sweep share its directory
        with pytest.raises(RunError, match=re.escape(f"{out / every[0].name} is in use by another smol-dsl process")):
            prepare(0, 2, resume=True)  # the same part twice
        with pytest.raises(RunError, match="is in use by another smol-dsl process"):
            prepare(0, 1, resume=True)  # the whole sweep beside its parts
    with prepare(0, 1, resume=True):
        code, err = cli(["sweep", "walker2d", "human", "smol", "--seeds", "2", *FLAGS, "--out", str(out)], capsys)
        assert code == 2 and "already exists and is not empty" in err
        code, err = cli(
            ["sweep", "walker2d", "human", "smol", "--seeds", "2", *FLAGS, "--out", str(out), "--resume"], capsys
        )
        assert code == 2 and f"{out} is in use by another smol-dsl process" in err


def test_a_sweep_resumed_after_a_run_directory_was_deleted_sets_it_up_again(library, tmp_path):
    out = tmp_path / "sweep"
    every = plan_sweep([library["human"]], [0, 1], CONFIG)
    prepare_sweep_directory(out, every, every, CONFIG, False, False, "sweep-checkpoint.npz").close()
    shutil.rmtree(out / every[1].name)
    prepare_sweep_directory(out, every, every, CONFIG, True, False, "sweep-checkpoint.npz").close()
    assert (out / every[1].name / "config.json").is_file()


def test_a_sweep_resumed_with_another_number_of_processes_is_refused(library, tmp_path):
    out = tmp_path / "sweep"
    every = plan_sweep([library["human"]], [0, 1], CONFIG)
    for part in (0, 1):
        name = f"sweep-checkpoint-{part}-of-2.npz"
        prepare_sweep_directory(out, every, every[part::2], CONFIG, False, True, name).close()
        (out / name).write_bytes(b"")  # stands for the checkpoint each process wrote
    with pytest.raises(RunError, match=r"was checkpointed by 2 processes \(--num-processes 2\).*not one process"):
        prepare_sweep_directory(out, every, every, CONFIG, True, False, "sweep-checkpoint.npz")
    (out / "sweep-checkpoint-1-of-2.npz").unlink()  # process 1 was killed before its first checkpoint:
    prepare_sweep_directory(out, every, every[1::2], CONFIG, True, True, "sweep-checkpoint-1-of-2.npz").close()


def test_a_refused_resume_names_each_differing_setting(small_run, tmp_path, capsys):
    out = copy_of(small_run, tmp_path)
    argv = ["run", "walker2d", "human", "--evals", "192", "--batch-size", "8", "--phases", "10"]
    argv += ["--centroids", "32", "--episode-length", "20", "--seed", "3", "--no-progress"]
    code, err = cli([*argv, "--out", str(out), "--resume"], capsys)
    assert code == 2
    assert f"{out} was started with different settings" in err
    assert "--evals: the run was started with 208, not 192" in err
    assert "--batch-size: the run was started with 16, not 8" in err
    assert "--seed: the run was started with 0, not 3" in err
    assert "{" not in err and "--phases:" not in err  # no JSON dump, nothing that agrees
    code, err = cli([*argv[:-1], "--out", str(out), "--resume"], capsys)  # with the progress bar
    assert code == 2 and "--evals: the run was started with 208, not 192" in err
    assert "gen/s" not in err and "%|" not in err  # refused before the bar appears
    code, err = cli(["run", "walker2d", "smol", *FLAGS, "--no-progress", "--out", str(out), "--resume"], capsys)
    assert code == 2 and "was started with a different schedule" in err and str(out / "schedule.sched") in err


def test_a_refused_sweep_resume_names_schedules_seeds_and_settings(library, tmp_path):
    out = tmp_path / "sweep"
    every = plan_sweep([library["human"], library["smol"]], [0, 1, 2], CONFIG)
    prepare_sweep_directory(out, every, every, CONFIG, False, False, "sweep-checkpoint.npz").close()
    other = preset_config(
        "walker2d", "quick", evaluations=208, batch_size=16, num_phases=10, num_centroids=16, episode_length=20
    )
    changed = plan_sweep([library["human"]], [0, 1], other)
    with pytest.raises(RunError) as caught:
        prepare_sweep_directory(out, changed, changed, other, True, False, "sweep-checkpoint.npz")
    message = str(caught.value)  # the library names its settings
    assert "num_centroids: the sweep was started with 32, not 16" in message
    assert "; schedules: the sweep was started with human, smol, not human" in message
    assert "; seeds: the sweep was started with seeds 0..2, not 0, 1" in message
    assert "{" not in message and "--" not in message
    worded = caught.value.worded(OPTIONS)  # the command line, its options
    assert "--centroids: the sweep was started with 32, not 16" in worded
    assert "SCHEDULE: the sweep was started with human, smol, not human" in worded
    assert "--first-seed/--seeds: the sweep was started with seeds 0..2, not 0, 1" in worded
