"""`smol-dsl sweep`: runs as one batched program, equal to single runs, resumable, one run
directory per (schedule, seed) (sharded over devices: test_devices)."""

from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from small_runs import CONFIG, FLAGS

from smol_dsl.cli import main
from smol_dsl.language.channels import GEAR
from smol_dsl.results.runs import load_runs
from smol_dsl.runner import RunError, load_archive, run_experiment, run_sweep
from smol_dsl.runner.engine import shared_engine, stack_runs
from smol_dsl.runner.sweep import plan_sweep

SCHEDULES = ("human", "extinction-50")
SEEDS = (0, 1)


@pytest.fixture(scope="module")
def schedules(library):
    return [library[name] for name in SCHEDULES]


@pytest.fixture(scope="module")
def sweep(schedules, tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "walker2d-sweep"
    return out, run_sweep("walker2d", schedules, SEEDS, CONFIG, out_dir=out)


def assert_same_runs(results, others, exact=False):
    """The same runs: bit for bit when both ran in the same program (`exact`); else the
    same events, counts, alphas and filled cells, and scores equal to float32 rounding
    (XLA compiles a rollout differently inside another program, which may round a last
    bit differently)."""
    assert len(results) == len(others)
    for a, b in zip(results, others, strict=True):
        fitnesses_a, fitnesses_b = np.asarray(a.repertoire.fitnesses), np.asarray(b.repertoire.fitnesses)
        if exact:
            np.testing.assert_array_equal(fitnesses_a, fitnesses_b)
            assert a.metrics == b.metrics
            continue
        np.testing.assert_array_equal(fitnesses_a > -np.inf, fitnesses_b > -np.inf)
        np.testing.assert_allclose(fitnesses_a, fitnesses_b, rtol=1e-5)
        assert len(a.metrics) == len(b.metrics)
        for x, y in zip(a.metrics, b.metrics, strict=True):
            assert {k: v for k, v in x.items() if not isinstance(v, float)} == {
                k: v for k, v in y.items() if not isinstance(v, float)
            }
            assert x["alpha"] == y["alpha"]
            for name in ("coverage", "max_fitness", "qd_score"):
                assert x[name] == pytest.approx(y[name], rel=1e-5)


@pytest.mark.slow
def test_a_sweep_run_equals_the_single_run(sweep, schedules):
    _, results = sweep
    for index in (0, 3):  # human seed 0, extinction-50 seed 1
        schedule, seed = schedules[index // 2], SEEDS[index % 2]
        single = run_experiment("walker2d", schedule, dataclasses.replace(CONFIG, seed=seed))
        assert results[index].config == single.config
        np.testing.assert_array_equal(results[index].alphas, single.alphas)
        assert_same_runs([results[index]], [single])


@pytest.mark.slow
def test_one_run_directory_per_pair_in_the_run_format(sweep, schedules):
    out, results = sweep
    names = sorted(p.name for p in out.iterdir() if p.is_dir())
    assert names == sorted(f"walker2d-{s}-seed{seed}" for s in SCHEDULES for seed in SEEDS)
    for result in results:
        directory = result.out_dir
        for file in ("config.json", "schedule.sched", "certificate.json", "metrics.csv", "archive.npz"):
            assert (directory / file).is_file(), file
        archive = load_archive(directory)
        np.testing.assert_array_equal(archive.fitnesses, np.asarray(result.repertoire.fitnesses).reshape(-1))
    groups = load_runs([out])  # what `report` reads
    assert [len(runs) for runs in groups.values()] == [2, 2]
    for result, run in zip(results, [r for runs in groups.values() for r in runs], strict=True):
        assert run.final["max_fitness"] == pytest.approx(result.final["max_fitness"])
    assert json.loads((out / "sweep.json").read_text())["runs"][0]["name"] == "walker2d-human-seed0"


@pytest.mark.slow
def test_every_run_reaches_the_standard_body(sweep):
    _, results = sweep
    for result in results:
        assert result.final["alpha"] == 1.0
        assert result.final["evaluations"] == 208


@pytest.mark.slow
def test_each_run_of_a_sweep_is_thinned_by_its_own_extinction(sweep):
    """The sweep's re-evaluation program, given one archive in its four runs with the same key
    and extinctions 0, 0.5, 1 and 0.5: the first keeps every elite, the third none, and the
    others exactly those whose draw from that key survives 0.5, alike in both."""
    _, results = sweep
    engine = shared_engine("walker2d", CONFIG, tuple(jax.local_devices()), 1, len(results), (GEAR,))
    archive = results[0].repertoire  # trained to the standard body: re-scored, its elites keep their cells
    cells = np.flatnonzero(np.asarray(archive.fitnesses).reshape(-1) > -np.inf)  # the order they are re-scored in
    assert 0 < len(cells) <= CONFIG.batch_size  # one chunk
    key = jax.random.key(11)
    fresh, counts = engine.reevaluate(
        engine.put(stack_runs([archive] * 4)),
        engine.put(jnp.ones((4, 1))),
        engine.put(stack_runs([engine.task.episode_start(0)] * 4)),
        engine.put(jnp.asarray([0.0, 0.5, 1.0, 0.5], jnp.float32)),
        engine.put(jnp.stack([key] * 4)),
    )
    kept = [set(np.flatnonzero(np.asarray(f).reshape(-1) > -np.inf)) for f in fresh.fitnesses]
    assert list(counts.reevaluated) == [len(cells)] * 4
    draws = jax.random.uniform(jax.random.split(key, 3)[2], (CONFIG.batch_size,))  # a chunk's death draws
    survivors = {int(cell) for cell, draw in zip(cells, np.asarray(draws)) if draw >= 0.5}
    assert kept[0] == set(cells) and kept[2] == set()
    assert kept[1] == kept[3] == survivors
    # in the body they were trained in, every survivor keeps its own cell: none moves or collides
    assert list(counts.kept) == [len(cells), len(survivors), 0, len(survivors)]
    assert list(counts.died) == [0, len(cells) - len(survivors), len(cells), len(cells) - len(survivors)]
    assert not counts.moved.any() and not counts.collided.any() and not counts.non_finite.any()


@pytest.mark.slow
def test_resume_after_interruption_equals_an_uninterrupted_sweep(sweep, schedules, tmp_path):
    _, uninterrupted = sweep
    out = tmp_path / "interrupted"
    partial = run_sweep("walker2d", schedules, SEEDS, CONFIG, out_dir=out, stop_after_generation=5)
    assert partial[0].final["generation"] == 5 and not (out / "walker2d-human-seed0" / "archive.npz").exists()
    resumed = run_sweep("walker2d", schedules, SEEDS, CONFIG, out_dir=out, resume=True)
    assert_same_runs(resumed, uninterrupted, exact=True)


@pytest.mark.slow
def test_sweep_refuses_to_overwrite_or_resume_something_else(sweep, schedules, library):
    out, _ = sweep
    with pytest.raises(RunError, match="already exists"):
        run_sweep("walker2d", schedules, SEEDS, CONFIG, out_dir=out)
    with pytest.raises(RunError, match="different settings, schedules or seeds"):
        run_sweep("walker2d", schedules, (0, 1, 2), CONFIG, out_dir=out, resume=True)
    with pytest.raises(RunError, match="share the directory walker2d-human-seed0"):
        plan_sweep([library["human"], library["human"]], [0], CONFIG)


@pytest.mark.slow
def test_cli_sweep_killed_then_resumed_equals_uninterrupted(sweep, tmp_path):
    """`smol-dsl sweep` killed with SIGKILL, then --resume, ends exactly as the uninterrupted
    sweep of this process (the same programs: the same settings and devices)."""
    _, uninterrupted = sweep
    out = tmp_path / "killed"
    command = [sys.executable, "-m", "smol_dsl.cli", "sweep", "walker2d", *SCHEDULES, "--seeds", "2", *FLAGS]
    command += ["--out", str(out), "--no-progress"]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and process.poll() is None:
        checkpoint = out / "sweep-checkpoint.npz"
        if checkpoint.is_file():
            try:
                with np.load(checkpoint) as data:
                    generation = json.loads(str(data["progress"]))[0]["generation"]
            except (OSError, ValueError, KeyError):
                generation = 0
            if generation >= 3:
                break
        time.sleep(0.2)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert not (out / "walker2d-human-seed0" / "archive.npz").exists(), "killed too late to test resuming"
    resumed = subprocess.run([*command, "--resume"], capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert "next: smol-dsl report" in resumed.stdout
    for name in ("metrics.png", "archive.png"):  # the CLI draws every finished run's figures
        assert all((out / result.out_dir.name / name).is_file() for result in uninterrupted), name
    for result in uninterrupted:
        archive, whole = load_archive(out / result.out_dir.name), load_archive(result.out_dir)
        np.testing.assert_array_equal(archive.fitnesses, whole.fitnesses)
        np.testing.assert_array_equal(archive.descriptors, whole.descriptors)
        metrics = (out / result.out_dir.name / "metrics.csv").read_text()
        assert metrics == (result.out_dir / "metrics.csv").read_text()
        phases = (out / result.out_dir.name / "phases.npz").read_bytes()
        assert phases == (result.out_dir / "phases.npz").read_bytes()  # every phase's snapshots, bit for bit


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["sweep", "unicycle", "human"], "unknown task 'unicycle'"),
        (["sweep", "walker2d", "human", "--devices", "64"], "--devices 64: this machine has"),
        (["sweep", "walker2d", "human", "--phases", "5"], "no phase lies wholly in the final-body tail"),
        (["sweep", "walker2d", "human", "--seeds", "0"], "must be at least 1"),
    ],
)
def test_cli_sweep_bad_input(args, message, tmp_path, capsys):
    try:
        code = main([*args, "--out", str(tmp_path / "s")])
    except SystemExit as exit:  # argparse's own checks
        code = exit.code
    assert code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_cli_sweep_bad_schedule_file(tmp_path, capsys):
    broken = tmp_path / "broken.sched"
    broken.write_text('name "broken"\nconstant 1 until %\n')
    assert main(["sweep", "walker2d", "human", str(broken), "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err
    assert "broken.sched:2:" in err and "Traceback" not in err
    assert not (tmp_path / "s").exists()


def test_processes_share_a_sweep_by_index(schedules, monkeypatch):
    from smol_dsl.cli import build_parser
    from smol_dsl.cli.run import sweep_part

    def part(*flags):
        return sweep_part(build_parser().parse_args(["sweep", "walker2d", "human", *flags]))

    assert part() == (0, 1)
    assert part("--num-processes", "3", "--process-id", "2") == (2, 3)
    monkeypatch.setenv("SLURM_NTASKS", "4")
    monkeypatch.setenv("SLURM_PROCID", "1")
    assert part("--cluster") == (1, 4)
    with pytest.raises(RunError, match="part 2 of 2 does not exist"):
        run_sweep("walker2d", schedules, SEEDS, CONFIG, part=(2, 2))
    with pytest.raises(RunError, match="4 runs, too few for 5 parts"):
        run_sweep("walker2d", schedules, SEEDS, CONFIG, part=(4, 5))


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--num-processes", "2"], "give --num-processes and --process-id together"),
        (["--num-processes", "2", "--process-id", "2"], "the index must be from 0 to 1"),
        (["--cluster"], "--cluster: no cluster launcher found"),
    ],
)
def test_cli_sweep_bad_process_flags(flags, message, tmp_path, capsys, monkeypatch):
    for name in ("SLURM_NTASKS", "SLURM_PROCID", "OMPI_COMM_WORLD_SIZE", "OMPI_COMM_WORLD_RANK"):
        monkeypatch.delenv(name, raising=False)
    assert main(["sweep", "walker2d", "human", *flags, "--out", str(tmp_path / "s")]) == 2
    assert message in capsys.readouterr().err


def test_devices_split_runs_first_then_populations():
    from smol_dsl.runner.layout import mesh_shape

    assert mesh_shape(devices=2, runs=15, batch_size=128) == (2, 1)  # 16 slots, one padded
    assert mesh_shape(devices=2, runs=1, batch_size=128) == (1, 2)  # one run, its batch halved
    assert mesh_shape(devices=8, runs=3, batch_size=128) == (2, 4)
    assert mesh_shape(devices=8, runs=3, batch_size=6) == (2, 1)  # 6 does not split in 4: idle
    assert mesh_shape(devices=1, runs=5, batch_size=7) == (1, 1)
