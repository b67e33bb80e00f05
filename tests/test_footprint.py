"""Paper scale by arithmetic: sizes, the compiled program's memory, refusals, the CLI estimate."""

from __future__ import annotations

import re

import jax
import jax.numpy as jnp
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
    assert main(["run", "walker2d", "human", "--preset", "paper", "--dry-run"]) == 0
    err = capsys.readouterr().err
    assert "what this will need, by arithmetic before compiling" in err
    assert "5,702 parameters" in err and "23.4 MB per run" in err
    assert re.search(r"to finish in 1 h: [\d.]+ k evals/s", err)
    assert not (tmp_path / "runs").exists()


def test_a_small_budget_s_rate_is_not_printed_as_zero(tmp_path, capsys):
    flags = ["--evals", "208", "--batch-size", "16", "--phases", "10", "--centroids", "32", "--episode-length", "20"]
    assert main(["run", "walker2d", "human", *flags, "--dry-run", "--out", str(tmp_path / "run")]) == 0
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
