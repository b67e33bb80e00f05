"""Checkpoints written in the background: one at a time, skipped while busy, errors surfaced."""

from __future__ import annotations

import threading

import jax.numpy as jnp
import numpy as np
import pytest

from smol_dsl.runner import RunError, checkpoint
from smol_dsl.runner.checkpoint import CheckpointWriter, host_copy


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
