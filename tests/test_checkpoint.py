"""Checkpoints: written in the background (one at a time, skipped while busy, errors
surfaced) from one host copy, and refused on resume when damaged, another run's, or shaped
for another policy."""

from __future__ import annotations

import shutil
import threading

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from small_runs import FLAGS, RUN, cli, copy_of, run_environment, small_config

from smol_dsl.rundir import RunDirectoryError
from smol_dsl.runner import RunError, checkpoint
from smol_dsl.runner.checkpoint import CheckpointWriter, host_copy, load_checkpoint
from smol_dsl.runner.directories import prepare_run_directory
from smol_dsl.tasks import make_task


@pytest.fixture
def slow_disk(monkeypatch):
    """write_npz held until the test releases it."""
    release, started, written = threading.Event(), threading.Event(), []

    def write(path, arrays):
        started.set()
        assert release.wait(30)
        written.append((path.name, {name: value.copy() for name, value in arrays.items()}))

    monkeypatch.setattr(checkpoint, "write_npz", write)
    return release, started, written


def test_training_goes_on_while_a_checkpoint_is_written_and_a_busy_writer_skips(tmp_path, slow_disk):
    release, started, written = slow_disk
    writer = CheckpointWriter()
    assert writer.offer(tmp_path / "a.npz", lambda: {"x": np.zeros(3)})  # returns while the write waits
    assert started.wait(30) and writer.writing()
    copied = []
    assert not writer.offer(tmp_path / "b.npz", lambda: copied.append(1) or {"x": np.ones(3)})
    assert copied == [] and writer.skipped == 1  # nothing is even copied to host memory
    release.set()
    writer.flush()
    assert not writer.writing() and [name for name, _ in written] == ["a.npz"] and writer.written == 1
    assert writer.offer(tmp_path / "c.npz", lambda: {"x": np.ones(3)})  # free again: not skipped
    writer.flush()
    assert [name for name, _ in written] == ["a.npz", "c.npz"] and writer.written == 2


def test_a_failed_background_write_is_raised_in_the_training_thread(tmp_path, monkeypatch):
    def full_disk(path, arrays):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(checkpoint, "write_npz", full_disk)
    writer = CheckpointWriter()
    writer.offer(tmp_path / "a.npz", lambda: {"x": np.zeros(3)})
    with pytest.raises(RunError, match=f"cannot write {tmp_path / 'a.npz'}: No space left"):  # names the file
        writer.flush()
    writer.flush()  # reported once


def test_leaving_a_run_with_an_error_keeps_that_error(tmp_path, monkeypatch):
    monkeypatch.setattr(checkpoint, "write_npz", lambda path, arrays: (_ for _ in ()).throw(OSError("disk")))
    with pytest.raises(KeyboardInterrupt):
        with CheckpointWriter() as writer:
            writer.offer(tmp_path / "a.npz", lambda: {"x": np.zeros(3)})
            raise KeyboardInterrupt


def test_a_real_background_write_is_whole_on_disk(tmp_path):
    with CheckpointWriter() as writer:
        writer.offer(tmp_path / "a.npz", lambda: {"x": np.arange(1000.0)})
    with np.load(tmp_path / "a.npz") as data:
        np.testing.assert_array_equal(data["x"], np.arange(1000.0))
    assert [p.name for p in tmp_path.iterdir()] == ["a.npz"]  # no temporary file left


def test_host_copy_owns_its_memory():
    """A CPU array's host view would change under a donated buffer; the copy does not."""
    device_array = jnp.arange(8.0)
    copy = host_copy(device_array)
    assert not np.shares_memory(copy, np.asarray(device_array))
    np.testing.assert_array_equal(copy, np.arange(8.0))


@pytest.mark.parametrize("rows", [None, 1, 3, 6, slice(1, 2), slice(2, 5), slice(4, 6)])
def test_host_copy_of_an_array_split_over_devices_is_one_copy_of_the_rows_asked_for(rows):
    """Filled shard by shard: the JAX array keeps no cached host copy of itself (which
    `np.asarray` would leave behind, a second copy of every archive in a checkpoint)."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    devices = jax.devices()[:2]
    mesh = Mesh(np.asarray(devices).reshape(len(devices), 1), ("runs", "population"))
    values = np.arange(6 * 5 * 3, dtype=np.float32).reshape(6, 5, 3)
    split = jax.device_put(values, NamedSharding(mesh, PartitionSpec("runs")))
    copy = host_copy(split, rows)
    expected = values if rows is None else values[rows if isinstance(rows, slice) else slice(0, rows)]
    np.testing.assert_array_equal(copy, expected)
    assert copy.flags.owndata and getattr(split, "_npy_value", None) is None


@pytest.mark.parametrize("damage", ["truncated", "empty", "flipped"])
def test_resume_from_a_damaged_checkpoint(small_run, tmp_path, capsys, damage):
    out = copy_of(small_run, tmp_path)
    path = out / "checkpoint.npz"
    data = path.read_bytes()
    damaged = {"truncated": data[: len(data) // 2], "empty": b"", "flipped": data[:300] + b"\xff" + data[301:]}
    path.write_bytes(damaged[damage])
    code, err = cli([*RUN, "--out", str(out), "--resume"], capsys)
    assert code == 2
    assert f"{path} cannot be resumed from: it is damaged" in err
    assert "delete checkpoint.npz and run the same command with --resume to start the run over" in err


def test_resume_from_a_checkpoint_of_another_run(small_run, library, tmp_path, capsys):
    """walker2d's and halfcheetah's archives have the same shapes: the checkpoint says whose it is."""
    out = tmp_path / "halfcheetah"
    cheetah = small_config("halfcheetah")
    prepare_run_directory(out, library["human"], cheetah, resume=False, environment=run_environment()).release()
    shutil.copy(small_run / "checkpoint.npz", out / "checkpoint.npz")
    code, err = cli(["run", "halfcheetah", "human", *FLAGS, "--no-progress", "--out", str(out), "--resume"], capsys)
    assert code == 2
    assert f"{out / 'checkpoint.npz'} cannot be resumed from: it was written by another run" in err
    assert "(task walker2d, not halfcheetah)" in err


def test_a_checkpoint_shaped_for_another_policy_is_refused(small_run):
    other = make_task("walker2d", episode_length=10, hidden_layer_sizes=(8, 8))
    template = other.init_policies(jax.random.key(0), 1)
    with pytest.raises(
        RunDirectoryError,
        match=r"its genotypes/params/Dense_0/bias has shape \(1, 32, 64\), but this one needs \(1, 32, 8\)",
    ):
        load_checkpoint(small_run / "checkpoint.npz", template, 1, 32, 2)


def test_sweep_checkpoint_that_is_not_one(tmp_path):
    path = tmp_path / "sweep-checkpoint.npz"
    path.write_bytes(b"not a zip file at all")
    with pytest.raises(RunDirectoryError, match="cannot be resumed from: it is damaged"):
        load_checkpoint(path, {"w": np.zeros((1, 3))}, 2, 16)
