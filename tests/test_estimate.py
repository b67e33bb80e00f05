"""The dry run's estimate of a sweep's wall time: its arithmetic on given numbers, and
`--dry-run` on real Brax physics (compiled and timed at the run-level tests' size), which
prints the measured throughput and the estimate and writes nothing."""

from __future__ import annotations

import os
import re

import pytest
from small_runs import FLAGS, cli

from smol_dsl.runner import preset_config
from smol_dsl.runner.estimate import Measurement, _duration, describe_estimate, estimate_duration

CONFIG = preset_config(
    "walker2d", "quick", evaluations=1000, batch_size=100, num_phases=5, num_centroids=256, episode_length=50
)
MEASURED = Measurement(
    runs=4,
    seeds=2,
    batch_size=100,
    episode_length=50,
    timed_generations=3,
    generation_seconds=2.0,
    chunk_seconds=1.5,
    centroids_seconds=2.5,
    compile_seconds=30.0,
    warmup_seconds=45.0,
)


def test_the_estimate_is_the_compile_the_centroids_every_batch_and_full_archives_at_every_boundary():
    duration = estimate_duration(CONFIG, MEASURED)
    # 1000 // 100 = 10 batches (the initial population and 9 generations); 4 boundaries;
    # a full archive of 256 cells is 3 chunks of 100
    assert (duration.batches, duration.boundaries, duration.chunks) == (10, 4, 3)
    assert duration.training_seconds == 10 * 2.0
    assert duration.reevaluation_seconds == 4 * 3 * 1.5
    assert duration.centroids_seconds == 2 * 2.5
    assert duration.total_seconds == 30.0 + 5.0 + 20.0 + 18.0
    assert MEASURED.evaluations_per_second == 4 * 100 / 2.0
    assert MEASURED.steps_per_second == 4 * 100 * 50 / 2.0


def test_a_run_of_one_phase_has_no_re_evaluation_and_whole_chunks_are_not_rounded_up():
    one_phase = preset_config("walker2d", "quick", evaluations=1000, batch_size=100, num_phases=1)
    assert estimate_duration(one_phase, MEASURED).reevaluation_seconds == 0
    even = preset_config("walker2d", "quick", batch_size=128, num_centroids=256)
    assert estimate_duration(even, MEASURED).chunks == 2


def test_the_estimate_as_printed_names_every_part_and_what_it_assumes():
    text = describe_estimate(CONFIG, MEASURED, "2 cpu devices")
    assert "throughput: 200 evals/s (10.0 k steps/s) over all 4 runs: a generation of 4 x 100 evaluations" in text
    assert "in 2.0 s (the mean of 3 timed after an untimed first)" in text
    assert (
        "compile: 30 s" in text and "a chunk of 100 elites of every run in 1.5 s; CVT centroids: 2.5 s a seed" in text
    )
    assert (
        "estimated wall time: 1 min 13 s = 30 s compile + 5.0 s centroids of 2 seed(s) + 10 batches x 2.0 s (20 s) "
        "+ up to 4 boundaries x 3 chunk(s) x 1.5 s (18 s)"
    ) in text
    assert "every archive full (256 cells) at every phase boundary" in text and "upper estimate" in text
    assert "(measured in 45 s on 2 cpu devices; nothing was written)" in text


@pytest.mark.parametrize(
    ("seconds", "shown"),
    [
        (0.42, "0.42 s"),
        (8.46, "8.5 s"),
        (42.4, "42 s"),
        (245, "4 min 5 s"),
        (3599.8, "1 h 0 min"),
        (12_000, "3 h 20 min"),
        (190_000, "2 d 5 h"),
    ],
)
def test_wall_times_read_as_people_read_them(seconds, shown):
    assert _duration(seconds) == shown


def test_no_measure_goes_with_dry_run(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))  # `sweep` sets it; restored after the test
    out = tmp_path / "out"
    code, err = cli(["sweep", "walker2d", "vanilla", *FLAGS, "--no-measure", "--out", str(out)], capsys)
    assert code == 2 and err.endswith(
        "smol-dsl sweep: error: --no-measure goes with --dry-run: it leaves out the dry run's measured warm-up\n"
    ), err
    assert not out.exists()


@pytest.mark.slow  # sizes the task by tracing it
def test_a_dry_run_without_measuring_prints_the_arithmetic_alone(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))
    code, err = cli(["sweep", "walker2d", "vanilla", *FLAGS, "--dry-run", "--no-measure"], capsys)
    assert code == 0, err
    assert "what this will need, by arithmetic before compiling" in err
    assert "measur" not in err and "estimated wall time" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow  # compiles and runs walker2d
@pytest.mark.parametrize(
    ("command", "runs"),
    [
        (["sweep", "walker2d", "vanilla", "human", "--seeds", "1"], "all 2 runs"),
        (["run", "walker2d", "human"], "the run"),
    ],
)
def test_a_dry_run_measures_the_sweep_on_this_machine_and_writes_nothing(tmp_path, monkeypatch, capsys, command, runs):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))
    out = tmp_path / "out"
    code, err = cli([*command, *FLAGS, "--dry-run", "--out", str(out)], capsys)
    assert code == 0, err
    assert "what this will need, by arithmetic before compiling" in err
    assert "measured on this machine:" in err
    assert re.search(rf"throughput: [\d.]+ (k )?evals/s \([\d.]+ [kM]? ?steps/s\) over {runs}: a generation of", err), (
        err
    )
    assert re.search(r"compile: [\d.]+ s|compile: \d+ min", err), err
    # FLAGS: 208 // 16 = 13 batches, 10 phases, 32 cells in chunks of 16
    assert re.search(
        r"estimated wall time: .+ = .+ compile \+ .+ \+ 13 batches x .+ \+ up to 9 boundaries x 2 chunk", err
    )
    assert not out.exists() and list(tmp_path.iterdir()) == []
