"""`run` and `sweep` against hostile input and a hostile environment (issue 9): every ordinary
mistake is exit status 2 with a message that names the file or option and says what to do;
never "internal error", never a traceback, and nothing half written left behind."""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from smol_dsl.cli import OPTIONS, main
from smol_dsl.errors import UserInputError
from smol_dsl.rundir import LOCK_FILE, atomic_write
from smol_dsl.rundir import files as rundir_files
from smol_dsl.rundir import metrics as rundir_metrics
from smol_dsl.runner import RunError, preset_config, run_experiment, run_sweep, schedule_key
from smol_dsl.runner import checkpoint as checkpoint_module
from smol_dsl.runner.checkpoint import CheckpointWriter, load_checkpoint
from smol_dsl.runner.directories import prepare_run_directory, prepare_sweep_directory
from smol_dsl.runner.lock import DirectoryLock
from smol_dsl.runner.sweep import plan_sweep
from smol_dsl.seeds import SEED_MAX, SeedError, check_seed
from smol_dsl.tasks import make_task

# the command-line flags and the same settings for the library: a run that compiles fast
FLAGS = ["--evals", "96", "--batch-size", "8", "--phases", "10", "--centroids", "16", "--episode-length", "10"]
CONFIG = preset_config(
    "walker2d", "quick", evaluations=96, batch_size=8, num_phases=10, num_centroids=16, episode_length=10
)
RUN = ["run", "walker2d", "human", *FLAGS, "--no-progress"]


def cli(argv, capsys):
    """main(argv) in this process: (exit status, stderr)."""
    try:
        code = main(argv)
    except SystemExit as exit:  # argparse's own refusals
        code = exit.code
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    return code, err


@pytest.fixture(scope="module")
def reference(library, tmp_path_factory):
    """An uninterrupted run with the settings of FLAGS, as `smol-dsl run` makes it."""
    out = tmp_path_factory.mktemp("reference") / "run"
    run_experiment("walker2d", library["human"], CONFIG, out_dir=out)
    return out


def copy_of(reference: Path, tmp_path: Path, name: str = "copy") -> Path:
    out = tmp_path / name
    shutil.copytree(reference, out)
    return out


def temporaries(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.rglob("*.tmp"))


# 1. --out that cannot be a directory, an empty --out ------------------------------------------


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


# 1. a read-only file system -------------------------------------------------------------------


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes into read-only directories")
def test_out_in_a_read_only_directory(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        code, err = cli([*RUN, "--out", str(locked / "run")], capsys)
    finally:
        locked.chmod(0o755)
    assert code == 2
    assert f"cannot create the run directory {locked / 'run'}: Permission denied" in err
    assert "give an --out where you can write" in err


def test_out_on_a_read_only_file_system(tmp_path, monkeypatch, capsys):
    """As root cannot be kept out by permissions, the file system says EROFS for one directory."""
    read_only = tmp_path / "mnt"
    real_mkdir = Path.mkdir

    def mkdir(self, *args, **kwargs):
        if read_only in (self, *self.parents):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))
        return real_mkdir(self, *args, **kwargs)

    monkeypatch.setattr(Path, "mkdir", mkdir)
    code, err = cli([*RUN, "--out", str(read_only / "run")], capsys)
    assert code == 2
    assert f"cannot create the run directory {read_only / 'run'}: Read-only file system" in err
    code, err = cli(["sweep", "walker2d", "human", "--seeds", "1", *FLAGS, "--out", str(read_only / "s")], capsys)
    assert code == 2 and f"cannot create the sweep directory {read_only / 's'}: Read-only file system" in err


def test_resume_where_nothing_can_be_written(reference, tmp_path, monkeypatch, capsys):
    out = copy_of(reference, tmp_path)

    def acquire(directory, what="run"):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(directory / LOCK_FILE))

    monkeypatch.setattr(DirectoryLock, "acquire", acquire)
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2
    assert f"cannot write in {out}: Read-only file system" in err and "--out COPY --resume" in err


# 1. a full disk -------------------------------------------------------------------------------


def full_disk_after(calls: int, real_write):
    """write_npz that writes `calls` files, then fails like a full disk part-way through
    the next (after some bytes reached the temporary file)."""
    count = [0]

    def write_npz(path, arrays):
        count[0] += 1
        if count[0] <= calls:
            return real_write(path, arrays)

        def partial(file):
            file.write(b"PK\x03\x04" + bytes(1000))
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        atomic_write(path, partial)

    return write_npz


def test_atomic_write_on_a_full_disk_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "checkpoint.npz"
    path.write_bytes(b"the last checkpoint")
    with pytest.raises(OSError) as caught:
        atomic_write(path, lambda file: (file.write(b"half"), (_ for _ in ()).throw(OSError(errno.ENOSPC, "full"))))
    assert caught.value.errno == errno.ENOSPC and caught.value.filename == str(path)
    assert path.read_bytes() == b"the last checkpoint"
    assert temporaries(tmp_path) == []


def test_a_background_checkpoint_on_a_full_disk_is_a_run_error(tmp_path, monkeypatch):
    path = tmp_path / "checkpoint.npz"
    checkpoint_module.write_npz(path, {"x": np.zeros(3)})
    monkeypatch.setattr(checkpoint_module, "write_npz", full_disk_after(0, checkpoint_module.write_npz))
    writer = CheckpointWriter()
    writer.offer(path, lambda: {"x": np.ones(3)})
    with pytest.raises(RunError) as caught:
        writer.flush()
    message = str(caught.value)
    assert f"cannot write {path}: No space left on device" in message
    assert f"the last checkpoint, {path}, is intact: free some space" in message and "--resume" in message
    with np.load(path) as data:
        np.testing.assert_array_equal(data["x"], np.zeros(3))
    assert temporaries(tmp_path) == []


def test_full_disk_while_checkpointing_then_resume(reference, tmp_path, monkeypatch, capsys):
    """`smol-dsl run` on a disk that fills up: exit 2 naming the checkpoint, the previous one
    intact, no temporary file; then --resume ends exactly like an uninterrupted run, even with
    rows written after that checkpoint left in metrics.csv."""
    out = tmp_path / "run"
    real = checkpoint_module.write_npz
    monkeypatch.setattr(checkpoint_module, "write_npz", full_disk_after(1, real))  # the first boundary's fails
    code, err = cli([*RUN, "--out", str(out)], capsys)
    assert code == 2
    assert f"cannot write {out / 'checkpoint.npz'}: No space left on device" in err
    assert f"the last checkpoint, {out / 'checkpoint.npz'}, is intact" in err and "--resume" in err
    assert temporaries(out) == [] and not (out / "archive.npz").exists()
    with np.load(out / "checkpoint.npz") as data:
        (saved,) = json.loads(str(data["progress"]))
    assert saved["generation"] == 0  # the initial population's, whole
    assert len((out / "metrics.csv").read_text().splitlines()) > 1 + len(saved["rows"])  # rows after it
    with open(out / "metrics.csv", "a") as file:  # and rows no checkpoint covers, twice
        file.write("".join((reference / "metrics.csv").read_text().splitlines(keepends=True)[-3:]) * 2)
    monkeypatch.setattr(checkpoint_module, "write_npz", real)
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 0, err
    assert (out / "metrics.csv").read_text() == (reference / "metrics.csv").read_text()
    with np.load(out / "archive.npz") as ours, np.load(reference / "archive.npz") as theirs:
        for name in theirs.files:
            np.testing.assert_array_equal(ours[name], theirs[name])


class FullAfter:
    """csv.DictWriter whose writerow fails like a full disk after `rows` rows."""

    rows = 0

    def __init__(self, real):
        self.real = real

    def __call__(self, *args, **kwargs):
        writer = self.real(*args, **kwargs)
        outer = self

        class Writer:
            def writeheader(self):
                return writer.writeheader()

            def writerows(self, rows):
                return writer.writerows(rows)

            def writerow(self, row):
                if outer.rows <= 0:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                outer.rows -= 1
                return writer.writerow(row)

        return Writer()


def test_full_disk_while_writing_metrics_then_resume_without_metrics(reference, library, tmp_path, monkeypatch):
    out = tmp_path / "run"
    full = FullAfter(rundir_metrics.csv.DictWriter)
    full.rows = 8
    monkeypatch.setattr(rundir_metrics.csv, "DictWriter", full)
    locked = []

    def progress(row, total):  # the run holds its directory's lock while it trains
        if row["generation"] == 3 and not locked:
            with pytest.raises(RunError, match="in use by another smol-dsl process"):
                DirectoryLock.acquire(out)
            locked.append(row)

    with pytest.raises(RunError) as caught:
        run_experiment("walker2d", library["human"], CONFIG, out_dir=out, progress=progress)
    monkeypatch.undo()
    assert locked
    DirectoryLock.acquire(out).release()  # and releases it when it stops, also on an error
    message = str(caught.value)
    assert f"cannot write {out / 'metrics.csv'}: No space left on device" in message
    assert f"the last checkpoint, {out / 'checkpoint.npz'}, is intact" in message
    (out / "metrics.csv").unlink()  # a deleted metrics.csv comes back from the checkpoint
    run_experiment("walker2d", library["human"], CONFIG, out_dir=out, resume=True)
    assert (out / "metrics.csv").read_text() == (reference / "metrics.csv").read_text()


def test_full_disk_while_setting_up_leaves_nothing(library, tmp_path, monkeypatch):
    out = tmp_path / "run"
    real = rundir_files.atomic_write
    written = []

    def atomic(path, write):
        if written:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        written.append(path)
        return real(path, write)

    monkeypatch.setattr(rundir_files, "atomic_write", atomic)
    with pytest.raises(RunError, match=r"schedule.sched: No space left on device; nothing was started"):
        run_experiment("walker2d", library["human"], CONFIG, out_dir=out)
    assert [p.name for p in out.iterdir() if p.name != LOCK_FILE] == []  # config.json removed again


def test_full_disk_in_a_sweep_names_its_checkpoint(library, tmp_path, monkeypatch):
    out = tmp_path / "sweep"
    monkeypatch.setattr(checkpoint_module, "write_npz", full_disk_after(1, checkpoint_module.write_npz))
    with pytest.raises(RunError) as caught:
        run_sweep("walker2d", [library["human"]], [0, 1], CONFIG, out_dir=out)
    message = str(caught.value)
    assert f"cannot write {out / 'sweep-checkpoint.npz'}: No space left on device" in message
    assert "is intact" in message and "--resume" in message
    assert temporaries(out) == []
    with np.load(out / "sweep-checkpoint.npz") as data:
        assert [p["generation"] for p in json.loads(str(data["progress"]))] == [0, 0]


# 1. a damaged checkpoint, one from another task, a damaged config.json ----------------------------


@pytest.mark.parametrize("damage", ["truncated", "empty", "flipped"])
def test_resume_from_a_damaged_checkpoint(reference, tmp_path, capsys, damage):
    out = copy_of(reference, tmp_path)
    path = out / "checkpoint.npz"
    data = path.read_bytes()
    damaged = {"truncated": data[: len(data) // 2], "empty": b"", "flipped": data[:300] + b"\xff" + data[301:]}
    path.write_bytes(damaged[damage])
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2
    assert f"{path} cannot be resumed from: it is damaged" in err
    assert "delete checkpoint.npz and run the same command with --resume to start the run over" in err


def test_resume_from_a_checkpoint_of_another_run(reference, library, tmp_path, capsys):
    """walker2d's and halfcheetah's archives have the same shapes: the checkpoint says whose it is."""
    out = tmp_path / "halfcheetah"
    cheetah = preset_config(
        "halfcheetah", "quick", evaluations=96, batch_size=8, num_phases=10, num_centroids=16, episode_length=10
    )
    prepare_run_directory(out, library["human"], cheetah, resume=False).release()
    shutil.copy(reference / "checkpoint.npz", out / "checkpoint.npz")
    code, err = cli(["run", "halfcheetah", "human", *FLAGS, "--no-progress", "--out", str(out), "--resume"], capsys)
    assert code == 2
    assert f"{out / 'checkpoint.npz'} cannot be resumed from: it was written by another run" in err
    assert "(task walker2d, not halfcheetah)" in err


def test_a_checkpoint_shaped_for_another_policy_is_refused(reference):
    other = make_task("walker2d", episode_length=10, hidden_layer_sizes=(8, 8))
    template = other.init_policies(jax.random.key(0), 1)
    with pytest.raises(
        RunError, match=r"its genotypes/params/Dense_0/bias has shape \(1, 16, 64\), but this one needs \(1, 16, 8\)"
    ):
        load_checkpoint(reference / "checkpoint.npz", template, 1, 16, 2)


def test_sweep_checkpoint_that_is_not_one(tmp_path):
    path = tmp_path / "sweep-checkpoint.npz"
    path.write_bytes(b"not a zip file at all")
    with pytest.raises(RunError, match="cannot be resumed from: it is damaged"):
        load_checkpoint(path, {"w": np.zeros((1, 3))}, 2, 16)


@pytest.mark.parametrize(
    ("text", "problem"), [("{", "not JSON"), ("[1, 2]", "not a JSON object"), ("\xff\xfe", "not JSON")]
)
def test_resume_with_a_damaged_config_json(reference, tmp_path, capsys, text, problem):
    out = copy_of(reference, tmp_path)
    (out / "config.json").write_bytes(text.encode("latin-1"))
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2
    assert f"{out / 'config.json'} is damaged ({problem}" in err and "put back a good copy" in err


def test_resume_of_a_sweep_as_a_run_and_of_a_run_as_a_sweep(reference, library, tmp_path, capsys):
    out = tmp_path / "sweep"
    every = plan_sweep([library["human"]], [0], CONFIG)
    prepare_sweep_directory(out, every, every, CONFIG, False, False, "sweep-checkpoint.npz").close()
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2 and f"{out} is a sweep directory, not a run's" in err
    code, err = cli(["sweep", "walker2d", "human", "--seeds", "1", *FLAGS, "--out", str(reference), "--resume"], capsys)
    assert code == 2 and f"{reference} is a run directory, not a sweep's" in err


def test_resume_without_its_schedule_file(reference, tmp_path, capsys):
    out = copy_of(reference, tmp_path)
    (out / "schedule.sched").unlink()
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2 and f"{out} holds no schedule.sched" in err


# 2. one process at a time in a run or sweep directory ----------------------------------------------

HOLD = """
import sys
from pathlib import Path
from smol_dsl.runner.lock import DirectoryLock
lock = DirectoryLock.acquire(Path(sys.argv[1]))
print("locked", flush=True)
sys.stdin.read()
"""


def test_a_second_process_on_a_run_directory_is_refused(reference, tmp_path, capsys):
    out = copy_of(reference, tmp_path)
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


def test_a_second_sweep_process_is_refused_but_parts_share_a_sweep(library, tmp_path, capsys):
    out = tmp_path / "sweep"
    schedules = [library["human"], library["smol"]]
    every = plan_sweep(schedules, [0, 1], CONFIG)

    def prepare(part, parts, resume=False):
        name = "sweep-checkpoint.npz" if parts == 1 else f"sweep-checkpoint-{part}-of-{parts}.npz"
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


# 3. seeds that would repeat another seed's stream ----------------------------------------------


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([*RUN, "--seed", "4294967296"], "--seed 4294967296: seeds are whole numbers from 0 to 4294967295"),
        ([*RUN, "--seed", "-1"], "--seed -1: seeds are whole numbers from 0 to 4294967295"),
        ([*RUN, "--seed", "99999999999999999999"], "--seed 99999999999999999999: seeds are whole numbers"),
        (["sweep", "walker2d", "human", *FLAGS, "--first-seed", "-3"], "--first-seed -3: seeds are whole numbers"),
        (
            ["sweep", "walker2d", "human", *FLAGS, "--first-seed", "4294967295", "--seeds", "2"],
            "--first-seed 4294967295 with --seeds 2: the seeds would run up to 4294967296",
        ),
    ],
)
def test_seeds_outside_the_distinct_range_are_refused(argv, message, tmp_path, capsys):
    code, err = cli([*argv, "--out", str(tmp_path / "out")], capsys)
    assert code == 2 and message in err
    assert not (tmp_path / "out").exists()


def test_the_seed_range_is_exactly_the_distinct_streams(library):
    assert check_seed(0) == 0 and check_seed(np.uint32(SEED_MAX), "--seed") == SEED_MAX
    for bad in (SEED_MAX + 1, -1, 2**70, 1.5, "3", True):
        with pytest.raises(SeedError):
            check_seed(bad)
    assert issubclass(SeedError, UserInputError) and issubclass(SeedError, ValueError)
    assert preset_config("walker2d", seed=SEED_MAX).seed == SEED_MAX
    with pytest.raises(SeedError, match="seed 4294967296"):
        preset_config("walker2d", seed=2**32)
    with pytest.raises(SeedError, match="seed -1"):
        plan_sweep([library["human"]], [0, -1], CONFIG)
    # the aliasing being refused: JAX keeps 32 bits, so these are the same stream
    np.testing.assert_array_equal(
        np.asarray(library["random"].phase_alphas(10, schedule_key(2**32))),
        np.asarray(library["random"].phase_alphas(10, schedule_key(0))),
    )
    assert not np.array_equal(
        np.asarray(library["random"].phase_alphas(10, schedule_key(SEED_MAX))),
        np.asarray(library["random"].phase_alphas(10, schedule_key(0))),
    )


# 4. a refused resume names each setting that differs ---------------------------------------------


def test_a_refused_resume_names_each_differing_setting(reference, tmp_path, capsys):
    out = copy_of(reference, tmp_path)
    argv = ["run", "walker2d", "human", "--evals", "192", "--batch-size", "16", "--phases", "10"]
    argv += ["--centroids", "16", "--episode-length", "10", "--seed", "3", "--no-progress"]
    code, err = cli([*argv, "--out", str(out), "--resume"], capsys)
    assert code == 2
    assert f"{out} was started with different settings" in err
    assert "--evals: the run was started with 96, not 192" in err
    assert "--batch-size: the run was started with 8, not 16" in err
    assert "--seed: the run was started with 0, not 3" in err
    assert "{" not in err and "--phases:" not in err  # no JSON dump, nothing that agrees
    code, err = cli(["run", "walker2d", "smol", *FLAGS, "--no-progress", "--out", str(out), "--resume"], capsys)
    assert code == 2 and "was started with a different schedule" in err and str(out / "schedule.sched") in err


def test_a_refused_sweep_resume_names_schedules_seeds_and_settings(library, tmp_path):
    out = tmp_path / "sweep"
    every = plan_sweep([library["human"], library["smol"]], [0, 1, 2], CONFIG)
    prepare_sweep_directory(out, every, every, CONFIG, False, False, "sweep-checkpoint.npz").close()
    other = preset_config(
        "walker2d", "quick", evaluations=96, batch_size=8, num_phases=10, num_centroids=32, episode_length=10
    )
    changed = plan_sweep([library["human"]], [0, 1], other)
    with pytest.raises(RunError) as caught:
        prepare_sweep_directory(out, changed, changed, other, True, False, "sweep-checkpoint.npz")
    message = str(caught.value)  # the library names its settings
    assert "num_centroids: the sweep was started with 16, not 32" in message
    assert "; schedules: the sweep was started with human, smol, not human" in message
    assert "; seeds: the sweep was started with seeds 0..2, not 0, 1" in message
    assert "{" not in message and "--" not in message
    worded = caught.value.worded(OPTIONS)  # the command line, its options
    assert "--centroids: the sweep was started with 16, not 32" in worded
    assert "SCHEDULE: the sweep was started with human, smol, not human" in worded
    assert "--first-seed/--seeds: the sweep was started with seeds 0..2, not 0, 1" in worded
