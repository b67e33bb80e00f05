"""Paper scale by arithmetic: sizes, the compiled program's memory, refusals, the CLI estimate."""

from __future__ import annotations

import contextlib
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from smol_dsl.cli import main
from smol_dsl.runner import RunError, preset_config
from smol_dsl.runner.engine import Engine, stack_runs
from smol_dsl.runner.footprint import DeviceMemory, device_memory, fit_sweep, plan_footprint
from smol_dsl.tasks import make_task, task_sizes

pytestmark = pytest.mark.slow  # every estimate starts from Brax tasks sized by tracing them

PAPER_SCHEDULES = [
    "vanilla",
    "smol",
    "smol-reverse",
    "human",
    "random",
    "extinction-05",
    "extinction-10",
    "extinction-50",
]


class FakeAccelerator:
    """A device as JAX describes one, with the memory an accelerator's allocator offers."""

    platform = "gpu"

    def __init__(self, gigabytes: float) -> None:
        self.limit = int(gigabytes * 1e9)

    def memory_stats(self) -> dict[str, int]:
        return {"bytes_limit": self.limit}


def test_task_sizes_by_tracing():
    ant = task_sizes("ant_omni", (256, 256))
    assert (ant.observations, ant.actions) == (27, 8)
    assert ant.parameters == 27 * 256 + 256 + 256 * 256 + 256 + 256 * 8 + 8
    walker = task_sizes("walker2d", (64, 64))
    assert (walker.observations, walker.actions, walker.descriptors) == (17, 6, 2)
    assert walker.state_bytes > 0


def test_paper_ant_archive_is_300_mb_per_run_and_24_gb_for_80_runs():
    config = preset_config("ant_omni", "paper")
    footprint = plan_footprint(config, 80, DeviceMemory("gpu", 1, 80 * 10**9, shares_host=False, host_bytes=10**12))
    assert 300e6 < footprint.archive_bytes < 310e6
    assert 24e9 < footprint.archives_bytes == footprint.checkpoint_bytes < 25e9
    assert footprint.device_archive_bytes == 2 * footprint.archives_bytes  # and its re-evaluated copy
    assert footprint.evaluations == 80 * (10_000_000 + 99 * 1024)


def test_batch_estimate_is_within_twice_the_compiled_programs_memory():
    """The arithmetic against XLA's own figures for the compiled parts of a generation: the
    archive it holds, and what choosing the offspring and scoring them need besides."""
    config = preset_config("walker2d", "quick", batch_size=32, episode_length=20, num_centroids=64)
    task = make_task("walker2d", episode_length=20, hidden_layer_sizes=config.hidden_layer_sizes)
    engine = Engine(
        task, batch_size=32, iso_sigma=0.005, line_sigma=0.05, devices=jax.devices()[:1], runs_per_step=1, num_runs=1
    )
    archives = engine.empty_archives(jax.random.uniform(jax.random.key(0), (1, 64, 2)))
    starts = engine.put(stack_runs([task.episode_start(0)]))
    alphas = engine.put(jnp.ones((1, 1), jnp.float32))  # one run, its body (alpha,)
    keys = engine.put(jax.random.split(jax.random.key(1), 1))
    ask = engine._ask.lower(archives, keys).compile().memory_analysis()
    offspring, _ = engine._ask(archives, keys)
    score = engine._scores.lower(offspring, alphas, starts).compile().memory_analysis()
    footprint = plan_footprint(config, 1, device_memory(jax.devices()[:1]), 1)
    assert ask.argument_size_in_bytes == pytest.approx(footprint.archive_bytes, rel=0.01)
    working = ask.temp_size_in_bytes + ask.output_size_in_bytes + score.temp_size_in_bytes
    assert 0.5 < footprint.batch_bytes / working < 2.0


def test_archive_programs_update_and_read_archives_in_place():
    """Runs one after another (runs_per_step 1) must not cost a copy of the archives: the
    compiled programs that read or update them need far less than one archive besides."""
    task = make_task("walker2d", episode_length=5, hidden_layer_sizes=(64, 64))
    devices = jax.devices()[:1]
    engine = Engine(task, batch_size=8, iso_sigma=0.005, line_sigma=0.05, devices=devices, runs_per_step=1, num_runs=4)
    archives = engine.empty_archives(jax.random.uniform(jax.random.key(0), (4, 256, 2)))
    keys = engine.put(jax.random.split(jax.random.key(1), 4))
    archive_bytes = sum(leaf.nbytes for leaf in jax.tree.leaves(archives))
    genotypes, _ = engine._ask(archives, keys)
    fitnesses, descriptors = jnp.zeros((4, 8)), jnp.zeros((4, 8, 2))
    programs = {
        "ask": engine._ask.lower(archives, keys),
        "tell": engine._tell.lower(archives, genotypes, fitnesses, descriptors),
        "metrics": engine._metrics.lower(archives),
    }
    for name, lowered in programs.items():
        temporary = lowered.compile().memory_analysis().temp_size_in_bytes
        assert temporary < archive_bytes / 8, (name, temporary, archive_bytes)


def test_runs_in_groups_equal_the_runs_vmapped():
    from smol_dsl.runner.engine import in_run_groups

    def one_run(x, key):
        return x.sum() + jax.random.normal(key, ()), x * 2

    xs = jnp.arange(6 * 4.0).reshape(6, 4)
    keys = jax.random.split(jax.random.key(3), 6)
    expected = jax.vmap(one_run)(xs, keys)
    for group in (1, 2, 4, 6, 9):  # 4: groups of 3, the largest divisor of the 6 runs up to 4
        for got, want in zip(jax.jit(lambda a, k, g=group: in_run_groups(one_run, (a, k), g))(xs, keys), expected):
            np.testing.assert_array_equal(got, want)


def test_a_sweep_too_big_for_the_device_is_refused_with_the_most_seeds_that_fit():
    config = preset_config("ant_omni", "paper")
    device = FakeAccelerator(16)
    with pytest.raises(RunError) as refused:
        fit_sweep(config, len(PAPER_SCHEDULES), range(10), [device])
    message = str(refused.value)
    most = int(re.search(r"At most --seeds (\d+) fits with 8 schedule\(s\)", message).group(1))
    assert "80 runs of ant_omni" in message and "16.0 GB of one gpu device" in message
    assert fit_sweep(config, 8, range(most), [device]).fits()
    with pytest.raises(RunError):
        fit_sweep(config, 8, range(most + 1), [device])


def test_one_run_that_cannot_fit_says_what_to_shrink():
    with pytest.raises(RunError, match="Not even one run fits: use fewer --centroids or a smaller --batch-size"):
        fit_sweep(preset_config("ant_omni", "paper"), 1, [0], [FakeAccelerator(0.5)])


def test_accelerators_advance_fewer_runs_at_once_when_all_do_not_fit():
    config = preset_config("ant_omni", "paper")
    roomy = fit_sweep(config, 4, [0], [FakeAccelerator(80)])
    assert roomy.parallel_runs == 4
    tight = fit_sweep(config, 4, [0], [FakeAccelerator(6)])
    assert tight.fits() and 1 <= tight.runs_per_step < 4
    assert not plan_footprint(config, 4, tight.memory, tight.runs_per_step + 1).fits()


def test_processes_share_the_memory_check():
    config = preset_config("ant_omni", "paper")
    alone = fit_sweep(config, 8, range(2), [FakeAccelerator(80)])
    shared = fit_sweep(config, 8, range(2), [FakeAccelerator(80)], part=(1, 4))
    assert (alone.runs, shared.runs) == (16, 4)


def test_cli_dry_run_prints_the_estimate_and_runs_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "walker2d", "human", "--preset", "paper", "--dry-run", "--no-measure"]) == 0
    err = capsys.readouterr().err
    assert "what this will need, by arithmetic before compiling" in err
    assert "5,702 parameters" in err and "23.4 MB per run" in err
    assert re.search(r"to finish in 1 h: [\d.]+ k evals/s", err)
    assert not (tmp_path / "runs").exists()


def test_a_small_budget_s_rate_is_not_printed_as_zero(tmp_path, capsys):
    flags = ["--evals", "208", "--batch-size", "16", "--phases", "10", "--centroids", "32", "--episode-length", "20"]
    assert main(["run", "walker2d", "human", *flags, "--dry-run", "--no-measure", "--out", str(tmp_path / "run")]) == 0
    err = capsys.readouterr().err
    assert re.search(r"to finish in 1 h: 0\.\d+ evals/s \([\d.]+ steps/s\); 24 h: 0\.00\d+ evals/s", err), err
    assert " 0 evals/s" not in err


def test_cli_refuses_a_sweep_whose_archives_cannot_fit(tmp_path, capsys):
    out = tmp_path / "sweep"
    code = main(["sweep", "ant_omni", *PAPER_SCHEDULES, "--seeds", "2000", "--preset", "paper", "--out", str(out)])
    assert code == 2
    err = capsys.readouterr().err
    assert re.search(r"error: 16000 runs of ant_omni need more than .* (At most --seeds \d+|Not even one run) fit", err)
    assert "Traceback" not in err and not out.exists()


class FakeHostCpu:
    """A CPU device as JAX describes one: no allocator limit, the host's memory is its."""

    platform = "cpu"


def test_a_sweep_too_big_for_the_host_is_refused_with_the_most_seeds_that_fit():
    config = preset_config("ant_omni", "paper")
    devices = [FakeHostCpu(), FakeHostCpu()]
    baseline = 500 * 10**6
    with pytest.raises(RunError) as refused:
        fit_sweep(config, 1, range(1000), devices, baseline_bytes=baseline)
    message = str(refused.value)
    assert "of host memory that the 2 cpu devices share" in message
    assert "for this process and its compiled programs" in message and "of archives held twice" in message
    most = int(re.search(r"At most --seeds (\d+) fits with 1 schedule\(s\)", message).group(1))
    assert most > 1
    fitting = fit_sweep(config, 1, range(most), devices, baseline_bytes=baseline)
    assert fitting.fits() and fitting.needed_bytes <= fitting.available_bytes
    with pytest.raises(RunError, match=f"At most --seeds {most} fits"):
        fit_sweep(config, 1, range(most + 1), devices, baseline_bytes=baseline)  # just over the limit


SWEEP_FLAGS = ["--evals", "192", "--batch-size", "64", "--phases", "2", "--episode-length", "10", "--no-progress"]
_SIZE = re.compile(r"= ([\d.]+) (kB|MB|GB) of [\d.]+ [kMGT]B host memory")
_UNITS = {"kB": 1e3, "MB": 1e6, "GB": 1e9}


def _sweeps(runs: list[tuple[int, Path]], centroids: int, dry_run: int = 0) -> list[tuple[str, float]]:
    """`smol-dsl sweep` processes as a user starts them, all at once (the first `dry_run` of
    them with `--dry-run --no-measure`): each one's output and
    the peak of its resident memory as the kernel counts it (VmHWM, read from outside until
    it exits: `ru_maxrss` of a child would include the memory of the process it was forked
    from)."""
    started = []
    for index, (seeds, out) in enumerate(runs):
        flags = ["--dry-run", "--no-measure"] if index < dry_run else []
        command = [sys.executable, "-c", "from smol_dsl.cli import main; raise SystemExit(main())", "sweep"]
        command += ["ant_omni", "vanilla", "--seeds", str(seeds), "--centroids", str(centroids), "--out", str(out)]
        log = tempfile.TemporaryFile("w+")
        process = subprocess.Popen([*command, *SWEEP_FLAGS, *flags], stdout=log, stderr=subprocess.STDOUT, text=True)
        started.append((process, log))
    peaks = [0] * len(started)
    while any(process.poll() is None for process, _ in started):
        for index, (process, _) in enumerate(started):
            with contextlib.suppress(OSError, AttributeError):  # not running any more
                status = Path(f"/proc/{process.pid}/status").read_text()
                peaks[index] = max(peaks[index], int(re.search(r"VmHWM:\s+(\d+) kB", status).group(1)) * 1024)
        time.sleep(0.02)
    results = []
    for (process, log), peak in zip(started, peaks, strict=True):
        log.seek(0)
        output = log.read()
        log.close()
        assert process.returncode == 0, output[-3000:]
        results.append((output, float(peak)))
    return results


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the peak resident memory is read from Linux's /proc")
def test_the_estimate_is_within_15_percent_of_the_measured_peak_of_1_and_10_ant_runs(tmp_path):
    """Sweeps as users start them, each in its own process: the estimate the sweep prints
    against the most memory it held (archives of 256 cells, ~77 MB a run): one run (what a
    process and its programs hold) and ten (what each run adds, its archives held twice)."""
    runs = [(seeds, tmp_path / f"sweep-{seeds}") for seeds in (1, 10)]
    dry_runs = [(seeds, tmp_path / f"dry-run-{seeds}") for seeds in (1, 10)]
    # the dry runs (seconds of arithmetic, each in its own process) beside the sweeps: each
    # process's own peak and its own estimate, whatever runs beside it
    results = _sweeps([*dry_runs, *runs], 256, dry_run=len(dry_runs))
    estimates = [_SIZE.search(output).groups() for output, _ in results[: len(dry_runs)]]
    peaks = [peak for _, peak in results[len(dry_runs) :]]
    measured = {
        seeds: (float(number) * _UNITS[unit], peak)
        for (seeds, _), (number, unit), peak in zip(runs, estimates, peaks, strict=True)
    }
    shown = {seeds: f"estimate {e / 1e9:.2f} GB, peak {p / 1e9:.2f} GB" for seeds, (e, p) in measured.items()}
    print(shown)
    for estimate, peak in measured.values():
        assert abs(estimate - peak) <= 0.15 * peak, shown
