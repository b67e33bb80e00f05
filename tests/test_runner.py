"""The phased MAP-Elites runner: phases, re-evaluation, budgets, outputs, resume, errors."""

from __future__ import annotations

import csv
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from small_runs import CONFIG, FLAGS, cli, small_config, small_task

import smol_dsl
from smol_dsl.qdax.phases import phase_of_generation
from smol_dsl.qdax.scoring import cvt_centroids
from smol_dsl.rundir import REEVALUATION_FIELDS
from smol_dsl.runner import (
    RunError,
    check_config,
    load_archive,
    preset_config,
    run_experiment,
    schedule_key,
)
from smol_dsl.runner.engine import Engine, shared_engine, stack_runs


@pytest.fixture(scope="session")
def task():
    return small_task()


@pytest.fixture(scope="session")
def human_run(small_result):
    return small_result


@pytest.mark.slow
def test_phases_follow_the_schedule(human_run, library):
    config = human_run.config
    expected = np.asarray(library["human"].phase_alphas(config.num_phases, schedule_key(config.seed)))
    np.testing.assert_array_equal(human_run.alphas, expected)
    for row in human_run.metrics:
        assert row["alpha"] == pytest.approx(float(expected[row["phase"]]))
        if row["event"] == "train":
            assert row["phase"] == phase_of_generation(row["generation"], config.generations, config.num_phases)
    phases = [row["phase"] for row in human_run.metrics]
    assert phases == sorted(phases) and phases[-1] == config.num_phases - 1
    assert human_run.final["alpha"] == 1.0  # the last phase is on the standard body


@pytest.mark.slow
def test_budget_and_reevaluation_counts(human_run):
    rows = human_run.metrics
    config = human_run.config
    assert rows[-1]["evaluations"] == (config.generations + 1) * config.batch_size == 208
    # every phase boundary re-evaluates exactly the cells filled just before it
    boundaries = [i for i, row in enumerate(rows) if row["event"] == "reevaluate"]
    assert len(boundaries) == config.num_phases - 1
    for i in boundaries:
        filled_before = round(rows[i - 1]["coverage"] * config.num_centroids / 100)
        assert rows[i]["reevaluations"] - rows[i - 1]["reevaluations"] == filled_before
        assert rows[i]["evaluations"] == rows[i - 1]["evaluations"]
        # ... and says what became of them: every elite kept, moved, collided or died, and the
        # cells filled after are those that kept or received an elite
        row = rows[i]
        assert row["reevaluated"] == filled_before
        assert row["kept"] + row["moved"] + row["collided"] + row["died"] == filled_before
        assert row["kept"] + row["moved"] == round(row["coverage"] * config.num_centroids / 100)
        assert row["died"] == row["non_finite"]  # human.sched has no extinction
    assert rows[-1]["reevaluations"] > 0
    assert all(row[name] is None for row in rows if row["event"] != "reevaluate" for name in REEVALUATION_FIELDS)


@pytest.mark.slow
def test_run_directory(human_run, library):
    out = human_run.out_dir
    for name in (
        "config.json",
        "schedule.sched",
        "certificate.json",
        "certificate.txt",
        "metrics.csv",
        "checkpoint.npz",
        "archive.npz",
    ):
        assert (out / name).is_file(), name
    assert not (out / "metrics.png").exists()  # figures are drawn from the files, after training
    assert (out / "schedule.sched").read_text() == library["human"].source
    with open(out / "metrics.csv") as file:
        rows = list(csv.DictReader(file))
    assert len(rows) == len(human_run.metrics)
    assert {
        "phase",
        "alpha",
        "evaluations",
        "reevaluations",
        "coverage",
        "max_fitness",
        "qd_score",
        "non_finite",
    } <= set(rows[0])
    archive = load_archive(out)
    assert archive.fitnesses.shape == (32,) and archive.descriptors.shape == (32, 2)
    assert np.all(np.isfinite(archive.fitnesses[archive.filled]))
    assert archive.filled.sum() == round(human_run.final["coverage"] * 32 / 100)
    assert archive.fitnesses.max() == pytest.approx(human_run.final["max_fitness"])


@pytest.mark.slow
def test_archive_elites_replay_to_their_fitness(human_run, task):
    archive = load_archive(human_run.out_dir)
    best = archive.best_cell
    params = jax.tree.map(lambda x: jnp.asarray(x)[None], archive.elite(best))
    fitness, descriptor = task.scoring_fn()(params, jnp.array([1.0]), task.episode_start(human_run.config.seed))
    assert float(fitness[0]) == pytest.approx(float(archive.fitnesses[best]), rel=1e-5)
    np.testing.assert_allclose(np.asarray(descriptor[0]), archive.descriptors[best], atol=1e-6)


@pytest.mark.slow
def test_same_seed_same_results(task, library, human_run):
    again = run_experiment(task, library["human"], small_config())
    assert again.metrics == human_run.metrics
    np.testing.assert_array_equal(np.asarray(again.repertoire.fitnesses), np.asarray(human_run.repertoire.fitnesses))


def test_a_finished_run_resumed_trains_nothing_and_changes_nothing(task, library, human_run, tmp_path, monkeypatch):
    """--resume of a finished run returns its result from the checkpoint: no episode start
    is made (no rollout can run), metrics.csv and archive.npz stay as they were."""
    out = tmp_path / "finished"
    shutil.copytree(human_run.out_dir, out)
    before = {name: (out / name).read_bytes() for name in ("metrics.csv", "archive.npz", "phases.npz")}
    monkeypatch.setattr(type(task), "episode_start", lambda self, seed: pytest.fail("a finished run made rollouts"))
    resumed = run_experiment(task, library["human"], small_config(), out_dir=out, resume=True)
    assert resumed.metrics == human_run.metrics
    assert {name: (out / name).read_bytes() for name in before} == before


@pytest.mark.slow
def test_resume_after_interruption_matches_an_uninterrupted_run(task, library, human_run, tmp_path):
    out = tmp_path / "interrupted"
    partial = run_experiment(task, library["human"], small_config(), out_dir=out, stop_after_generation=6)
    assert partial.final["generation"] == 6
    assert not (out / "archive.npz").exists()
    with pytest.raises(RunError, match="use --resume"):
        run_experiment(task, library["human"], small_config(), out_dir=out)
    resumed = run_experiment(task, library["human"], small_config(), out_dir=out, resume=True)
    assert resumed.metrics == human_run.metrics
    assert (out / "metrics.csv").read_text() == (human_run.out_dir / "metrics.csv").read_text()
    assert (out / "phases.npz").read_bytes() == (human_run.out_dir / "phases.npz").read_bytes()
    ours, theirs = np.load(out / "archive.npz"), np.load(human_run.out_dir / "archive.npz")
    assert sorted(ours.files) == sorted(theirs.files)
    for name in ours.files:
        np.testing.assert_array_equal(ours[name], theirs[name])


@pytest.mark.slow
def test_resume_refuses_other_settings(task, library, human_run, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(human_run.out_dir, out)
    with pytest.raises(RunError, match="different settings"):
        run_experiment(task, library["human"], small_config(seed=1), out_dir=out, resume=True)
    with pytest.raises(RunError, match="different schedule"):
        run_experiment(task, library["smol"], small_config(), out_dir=out, resume=True)
    with pytest.raises(RunError, match="no run to resume"):
        run_experiment(task, library["smol"], small_config(), out_dir=tmp_path / "none", resume=True)


@pytest.mark.slow
def test_extinction_of_every_elite_reseeds(task):
    everyone_dies = smol_dsl.parse("extinction 100%\n0% .. 100%: tail\n")
    result = run_experiment(task, everyone_dies, small_config())
    events = [row["event"] for row in result.metrics]
    assert events.count("reseed") == small_config().num_phases - 1
    for row in result.metrics:
        if row["event"] == "reevaluate":
            assert row["coverage"] == 0.0


def one_run_engine(task, batch_size=16):
    """An engine of its own for one run laid out as the small runs' (its population split
    between the devices: the programs that do not score are theirs), and that run's inputs
    (alpha 1, seed 0)."""
    engine = Engine(task, batch_size=batch_size, iso_sigma=0.005, line_sigma=0.05, num_runs=1)
    return engine, *run_inputs(engine)


def run_inputs(engine):
    """One run's episode start (seed 0) and body (alpha 1) on the engine's devices."""
    start = engine.put(stack_runs([engine.task.episode_start(0)]))
    return start, engine.put(jnp.ones((1, 1), jnp.float32))


def filled(repertoire):
    return int(np.sum(np.asarray(repertoire.fitnesses) > -np.inf))


@pytest.mark.slow
def test_extinction_removes_about_p_of_the_elites(task):
    """On the engine of the human run, in an archive of its size with every cell filled
    (fresh policies put in by hand): 30 draws of extinction at 0.5 kill about half of the
    elites re-scored, none die at 0 and all at 1; once the elites are in the cells of their
    own scores, a re-evaluation in the same body keeps every one in its cell."""
    from smol_dsl.qdax.scoring import LANE

    engine = shared_engine(task, CONFIG, tuple(jax.local_devices()), 1, 1)
    start, alpha = run_inputs(engine)
    cells = CONFIG.num_centroids
    centroids = cvt_centroids(cells, task.descriptor_low, task.descriptor_high, 5000, jax.random.key(0))
    policies = task.init_policies(jax.random.key(7), cells)
    archive = engine.empty_archives(centroids[None])
    archive = jax.tree.map(lambda x: jnp.asarray(x)[0], jax.device_get(archive))
    archive = archive.add(policies, centroids, jnp.zeros((cells,)), {LANE: jnp.zeros((cells,), jnp.int32)})
    archive = jax.tree.map(lambda x: np.asarray(x)[None], archive)
    assert filled(archive) == cells

    def reevaluated(source, extinction, seed):
        rate, key = engine.put(jnp.full((1,), extinction, jnp.float32)), engine.put(jax.random.key(seed)[None])
        fresh, counts = engine.reevaluate(engine.put(source), alpha, start, rate, key)
        assert counts.non_finite[0] == 0
        return jax.device_get(fresh), counts

    def died(extinction, seed):
        _, counts = reevaluated(archive, extinction, seed)
        assert counts.reevaluated[0] == cells
        return int(counts.died[0])

    assert died(0.0, 0) == 0  # nobody is lost but by extinction
    deaths = [died(0.5, k) for k in range(1, 31)]
    assert 0.38 < np.mean(deaths) / cells < 0.62
    assert died(1.0, 0) == cells
    scored, _ = reevaluated(archive, 0.0, 0)  # every elite in the cell of its own score
    _, counts = reevaluated(scored, 0.0, 1)  # same alpha, same cells
    assert counts.kept[0] == counts.reevaluated[0] == filled(scored) >= 1 and counts.died[0] == 0


@pytest.mark.slow
def test_an_empty_archive_is_reseeded_beside_a_filled_one_as_each_alone(task):
    """Two runs on one device, one archive empty and one filled: the empty one gets fresh
    policies, the filled one offspring, each bit for bit what a step of that run alone gives
    (the engine makes fresh policies only when some local archive is empty), scored alike to
    float32 rounding."""
    pair = shared_engine(task, CONFIG, tuple(jax.local_devices()[:1]), 1, 2)  # two runs on one device
    alone = shared_engine(task, CONFIG, tuple(jax.local_devices()), 1, 1)  # the small runs' own engine
    start, alpha = run_inputs(alone)
    centroids = cvt_centroids(32, task.descriptor_low, task.descriptor_high, 5000, jax.random.key(0))[None]
    first, *_ = alone.step(alone.empty_archives(centroids), alpha, start, alone.put(jax.random.key(1)[None]))
    empty, full = jax.device_get(alone.empty_archives(centroids)), jax.device_get(first)  # steps donate archives
    keys = jnp.stack([jax.random.key(2), jax.random.key(3)])
    expected = [
        alone.step(alone.put(archive), alpha, start, alone.put(keys[r : r + 1]))[0]
        for r, archive in enumerate((empty, full))
    ]
    pairs = lambda a, b: pair.put(jax.tree.map(lambda x, y: np.concatenate([x, y]), a, b))  # noqa: E731
    starts = jax.device_get(start)
    stepped, _, _, reseeded = pair.step(
        pairs(empty, full), pairs(np.asarray(alpha), np.asarray(alpha)), pairs(starts, starts), pair.put(keys)
    )
    assert list(reseeded) == [True, False]
    for r, archive in enumerate(expected):
        for ours, theirs in zip(jax.tree.leaves(stepped.genotypes), jax.tree.leaves(archive.genotypes), strict=True):
            np.testing.assert_array_equal(np.asarray(ours)[r], np.asarray(theirs)[0])
        # the two layouts compile the rollout apart: jax 0.12 can round a step 1 ulp apart
        np.testing.assert_allclose(np.asarray(stepped.fitnesses)[r], np.asarray(archive.fitnesses)[0], rtol=1e-6)
        np.testing.assert_allclose(np.asarray(stepped.descriptors)[r], np.asarray(archive.descriptors)[0], atol=1e-6)


@pytest.mark.slow
def test_non_finite_results_never_enter_the_archive(task, monkeypatch):
    real_score = task.score

    def poisoned(params, alpha, start):
        fitnesses, descriptors = real_score(params, alpha, start)
        bad = jnp.arange(fitnesses.shape[0]) % 3 == 0
        fitnesses = jnp.where(bad, jnp.nan, fitnesses)
        descriptors = jnp.where((jnp.arange(fitnesses.shape[0]) % 3 == 1)[:, None], jnp.inf, descriptors)
        return fitnesses, descriptors

    import dataclasses

    poisoned_task = dataclasses.replace(task)
    object.__setattr__(poisoned_task, "score", poisoned)
    engine, start, alpha = one_run_engine(poisoned_task)
    # each device scores its share of the batch: indices 0, 1, 3, 4, ... of each share are poisoned
    share = engine.batch_size // engine.population_devices
    poisoned_count = engine.population_devices * sum(i % 3 != 2 for i in range(share))
    centroids = cvt_centroids(32, task.descriptor_low, task.descriptor_high, 2000, jax.random.key(0))
    archive, _, dropped, reseeded = engine.step(
        engine.empty_archives(centroids[None]), alpha, start, engine.put(jax.random.key(1)[None])
    )
    assert bool(reseeded[0]) and int(dropped[0]) == poisoned_count
    archive, _, dropped, reseeded = engine.step(archive, alpha * 1.2, start, engine.put(jax.random.key(2)[None]))
    assert not bool(reseeded[0]) and int(dropped[0]) == poisoned_count
    rate = engine.put(jnp.zeros((1,), jnp.float32))
    before = int(np.sum(np.asarray(archive.fitnesses) > -np.inf))
    archive, counts = engine.reevaluate(archive, alpha * 0.8, start, rate, engine.put(jax.random.key(3)[None]))
    fitnesses = np.asarray(archive.fitnesses).reshape(-1)
    # no extinction: the elites that died are the non-finite ones; the others fill the cells
    assert counts.reevaluated[0] == before and counts.died[0] == counts.non_finite[0]
    assert counts.kept[0] + counts.moved[0] == counts.filled[0] == np.sum(fitnesses > -np.inf)
    assert counts.kept[0] + counts.moved[0] + counts.collided[0] + counts.died[0] == before
    assert np.all(np.isfinite(fitnesses[fitnesses > -np.inf]))
    assert np.all(np.isfinite(np.asarray(archive.descriptors).reshape(-1, 2)[fitnesses > -np.inf]))


@pytest.mark.slow
def test_a_phase_of_nothing_but_non_finite_results_stops_the_run(tmp_path, monkeypatch):
    """A body the physics cannot simulate (here gear 1e30, which `check --task` refuses: the
    proof is switched off to reach the physics) stops the run at the end of its first phase,
    instead of training on an empty archive."""
    from smol_dsl.tasks import registry

    monkeypatch.setattr(registry, "check_resolved_factors", lambda *args: None)
    huge = smol_dsl.parse("0% .. 50%: constant 1e30\n50% .. 100%: tail\n", path="huge.sched")
    out = tmp_path / "run"
    with pytest.raises(RunError) as caught:
        run_experiment("walker2d", huge, CONFIG, out_dir=out)
    message = str(caught.value)
    assert re.match(
        r"walker2d-huge-seed0: all \d+ evaluations of phase 0 scored NaN or infinity, under the body "
        r"alpha 1e\+30: the physics of walker2d cannot simulate it",
        message,
    ), message
    assert "smol-dsl check --task walker2d" in message
    rows = list(csv.DictReader(open(out / "metrics.csv")))
    assert rows[-1]["phase"] == "0" and (out / "checkpoint.npz").is_file() and not (out / "archive.npz").exists()


def test_config_checks(library):
    with pytest.raises(ValueError, match="use num_phases 10 or more"):
        check_config(small_config(num_phases=9), library["human"])
    check_config(small_config(num_phases=9), library["vanilla"])  # vanilla is all tail
    with pytest.raises(ValueError, match="use evaluations 2688 or more"):
        check_config(small_config(num_phases=20, batch_size=128, evaluations=1000), library["smol"])
    with pytest.raises(ValueError, match="num_centroids must be at least 2"):
        check_config(small_config(num_centroids=1), library["smol"])
    paper = preset_config("walker2d", "paper")
    assert (paper.evaluations, paper.batch_size, paper.num_phases, paper.num_centroids, paper.episode_length) == (
        10_000_000,
        8192,
        100,
        1024,
        1000,
    )
    assert preset_config("ant_omni", "paper").hidden_layer_sizes == (256, 256)


def _cli(*args, cwd):
    command = [sys.executable, "-m", "smol_dsl.cli", *args]
    return subprocess.Popen(command, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


CLI_RUN = ["run", "walker2d", "human", *FLAGS, "--no-progress"]  # the human run's settings


@pytest.mark.slow
def test_kill_9_then_resume_equals_uninterrupted_run(human_run, tmp_path):
    """`smol-dsl run` killed with SIGKILL after a few checkpointed phases, then --resume, ends
    exactly as the same run uninterrupted: the human run of this process, whose programs the
    CLI's are (the same settings and devices) and loads from the session's compilation cache."""
    killed = _cli(*CLI_RUN, "--out", "killed", cwd=tmp_path)
    metrics = tmp_path / "killed" / "metrics.csv"
    deadline = time.time() + 600
    while time.time() < deadline:  # kill once a few phases are checkpointed
        if metrics.is_file() and metrics.read_text().count("reevaluate") >= 3:
            break
        time.sleep(0.05)
    killed.send_signal(signal.SIGKILL)
    killed.wait()
    assert not (tmp_path / "killed" / "archive.npz").exists()
    resumed = _cli(*CLI_RUN, "--out", "killed", "--resume", cwd=tmp_path)
    out, err = resumed.communicate(timeout=600)
    assert resumed.returncode == 0, err
    assert "done: walker2d under SMOL-Human" in out
    assert out.splitlines()[0].startswith("done:"), out  # no MJX Warp lines before it
    assert "not actively being maintained" not in err and not (tmp_path / "MUJOCO_LOG.TXT").exists()
    assert all((tmp_path / "killed" / name).is_file() for name in ("metrics.png", "archive.png"))  # the CLI drew them
    assert (tmp_path / "killed" / "metrics.csv").read_text() == (human_run.out_dir / "metrics.csv").read_text()
    assert (tmp_path / "killed" / "phases.npz").read_bytes() == (human_run.out_dir / "phases.npz").read_bytes()
    ours, theirs = np.load(tmp_path / "killed" / "archive.npz"), np.load(human_run.out_dir / "archive.npz")
    for name in theirs.files:
        np.testing.assert_array_equal(ours[name], theirs[name])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "unicycle", "human"], "unknown task 'unicycle'"),
        (["run", "walker2d", "nope.sched"], "no such file"),
        (["run", "walker2d", "human", "--phases", "5"], "--phases 10 or more"),
        (["run", "walker2d", "human", "--evals", "100"], "generations"),
        (["run", "walker2d", "human", "--preset", "huge"], "unknown preset"),
        (["run", "walker2d", "human", "--evals", "0"], "must be at least 1"),
    ],
)
def test_cli_run_bad_input(tmp_path, monkeypatch, capsys, args, message):
    """In this process (the refusals come before anything is built; test_cli runs the console
    script itself on bad input)."""
    monkeypatch.chdir(tmp_path)
    code, err = cli(args, capsys)
    assert code == 2 and message in err


def test_cli_refuses_to_overwrite(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "something").write_text("precious")
    code, err = cli([*CLI_RUN, "--out", "taken"], capsys)
    assert code == 2 and "already exists" in err
    assert (tmp_path / "taken" / "something").read_text() == "precious"
    assert os.listdir(tmp_path / "taken") == ["something"]


@pytest.mark.slow
def test_phase_snapshots_are_the_archive_at_each_phase_s_start_and_end(human_run):
    """phases.npz holds the archive after the initial population, before and after every
    boundary's re-evaluation and at the end: their coverage is metrics.csv's at those rows,
    the last is the final archive, and none holds policies."""
    from smol_dsl.rundir.snapshots import END, START, read_snapshots

    config = small_config()
    snapshots = read_snapshots(human_run.out_dir)
    assert [(s.phase, s.moment) for s in snapshots] == [
        (phase, moment) for phase in range(config.num_phases) for moment in (START, END)
    ]
    rows = human_run.metrics
    by_generation = {}
    for row in rows:  # a boundary's reevaluate row follows the phase's last train row
        by_generation.setdefault(row["generation"], []).append(row)
    for snapshot in snapshots:
        at = by_generation[snapshot.generation]
        row = at[0] if snapshot.moment == END or snapshot.generation == 0 else at[-1]
        if snapshot.moment == START and snapshot.generation > 0:
            assert row["event"] == "reevaluate"
        coverage = 100 * snapshot.filled.sum() / config.num_centroids
        assert coverage == pytest.approx(row["coverage"]), snapshot
    final = np.load(human_run.out_dir / "archive.npz")
    np.testing.assert_array_equal(snapshots[-1].fitnesses, final["fitnesses"])
    np.testing.assert_array_equal(snapshots[-1].descriptors, final["descriptors"])
    assert not [name for name in np.load(human_run.out_dir / "phases.npz").files if "genotypes" in name]
