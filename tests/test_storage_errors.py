"""A full disk or a read-only file system while a run is set up, trains or checkpoints: one
message naming the file and saying that the last checkpoint is intact, nothing half written
left behind, and a resume that ends exactly as an uninterrupted run."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import numpy as np
import pytest
from small_runs import CONFIG, FLAGS, RUN, cli, copy_of, temporaries

from smol_dsl.rundir import LOCK_FILE, atomic_write
from smol_dsl.rundir import files as rundir_files
from smol_dsl.rundir import metrics as rundir_metrics
from smol_dsl.runner import RunError, run_experiment, run_sweep
from smol_dsl.runner import checkpoint as checkpoint_module
from smol_dsl.runner.checkpoint import CheckpointWriter
from smol_dsl.runner.lock import DirectoryLock


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


@pytest.mark.slow  # `run` sizes the Brax task before it creates the directory
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


def test_resume_where_nothing_can_be_written(small_run, tmp_path, monkeypatch, capsys):
    out = copy_of(small_run, tmp_path)

    def acquire(directory, what="run"):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(directory / LOCK_FILE))

    monkeypatch.setattr(DirectoryLock, "acquire", acquire)
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2
    assert f"cannot write in {out}: Read-only file system" in err and "--out COPY --resume" in err


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


def test_full_disk_while_checkpointing_then_resume(small_run, tmp_path, monkeypatch, capsys):
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
        file.write("".join((small_run / "metrics.csv").read_text().splitlines(keepends=True)[-3:]) * 2)
    monkeypatch.setattr(checkpoint_module, "write_npz", real)
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 0, err
    assert (out / "metrics.csv").read_text() == (small_run / "metrics.csv").read_text()
    with np.load(out / "archive.npz") as ours, np.load(small_run / "archive.npz") as theirs:
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


def test_full_disk_while_writing_metrics_then_resume_without_metrics(small_run, library, tmp_path, monkeypatch):
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
    assert (out / "metrics.csv").read_text() == (small_run / "metrics.csv").read_text()


@pytest.mark.slow  # `run` sizes the Brax task before it sets the directory up
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
    with pytest.raises(RunError, match=r"environment.json: No space left on device; nothing was started"):
        run_experiment("walker2d", library["human"], CONFIG, out_dir=out)  # the second file the run writes
    assert [p.name for p in out.iterdir() if p.name != LOCK_FILE] == []  # config.json removed again


@pytest.mark.slow
def test_full_disk_in_a_sweep_names_its_checkpoint(library, tmp_path, monkeypatch):
    """(test_sweep's four runs: its engine)"""
    out = tmp_path / "sweep"
    monkeypatch.setattr(checkpoint_module, "write_npz", full_disk_after(1, checkpoint_module.write_npz))
    with pytest.raises(RunError) as caught:
        run_sweep("walker2d", [library["human"], library["extinction-50"]], [0, 1], CONFIG, out_dir=out)
    message = str(caught.value)
    assert f"cannot write {out / 'sweep-checkpoint.npz'}: No space left on device" in message
    assert "is intact" in message and "--resume" in message
    assert temporaries(out) == []
    with np.load(out / "sweep-checkpoint.npz") as data:
        assert [p["generation"] for p in json.loads(str(data["progress"]))] == [0, 0, 0, 0]
