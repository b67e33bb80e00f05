"""The physics a task is simulated with (`--physics spring|mjx`): the body written into the
fields MJX reads, each channel changing what it should there, MuJoCo's own inverse weights
for a heavier body, the feet-contact descriptor from MJX's contacts, and physics as part of a
run's identity (config.json, environment.json; mixing refused by report, explore and resume)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from small_runs import cli
from synthetic_runs import snapshot, write_run

from smol_dsl.errors import UserInputError
from smol_dsl.results.runs import ReportError, load_runs
from smol_dsl.rundir import describe_environment, environment_differences, read_config
from smol_dsl.rundir.environment import environment_text
from smol_dsl.rundir.layout import ENVIRONMENT_FILE, LOCK_FILE, RunDirectoryError
from smol_dsl.runner import preset_config
from smol_dsl.tasks import make_task
from smol_dsl.tasks.physics import (
    MJX_IMPLEMENTATION,
    PHYSICS_NAMES,
    check_mjx_implementation,
    check_physics,
    physics_record,
)

CHANNELS = ["gear", "mass", "friction", "gravity"]


# -- names, settings and records (no physics runs) -------------------------------------------


def test_an_unknown_physics_is_refused_with_the_physics_there_are():
    with pytest.raises(
        ValueError, match=r"unknown physics 'bullet'; the physics are spring, mjx \(spring by default\)"
    ):
        check_physics("bullet")
    with pytest.raises(ValueError, match="unknown physics 'bullet'"):
        make_task("walker2d", physics="bullet")
    assert PHYSICS_NAMES == ("spring", "mjx")


def test_a_config_records_its_physics_and_one_without_it_is_springs(tmp_path):
    config = preset_config("walker2d", physics="mjx")
    path = tmp_path / "config.json"
    path.write_text(config.to_json())
    assert json.loads(path.read_text())["physics"] == "mjx" and read_config(path) == config
    data = json.loads(path.read_text())
    del data["physics"]  # a run directory from before physics could be chosen
    path.write_text(json.dumps(data))
    assert read_config(path).physics == "spring"
    path.write_text(json.dumps({**data, "physics": "bullet"}))
    with pytest.raises(RunDirectoryError, match="unknown physics 'bullet'"):
        read_config(path)


def test_environment_json_records_the_physics_and_compares_it():
    spring, mjx = describe_environment([], physics="spring"), describe_environment([], physics="mjx")
    assert (
        mjx["physics"]
        == physics_record("mjx")
        == {
            "name": "mjx",
            "package": "mujoco-mjx",
            "version": mjx["physics"]["version"],
            "implementation": "jax",
        }
    )
    assert spring["physics"]["package"] == "brax" and spring["physics"]["version"] == spring["packages"]["brax"]
    differences = environment_differences(spring, mjx)
    assert "physics name spring -> mjx" in differences and "physics package brax -> mujoco-mjx" in differences
    recorded_before_physics = {key: value for key, value in spring.items() if key != "physics"}
    assert environment_differences(recorded_before_physics, spring) == []  # such a run was spring's


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "walker2d", "human", "--physics", "bullet"], "invalid choice: 'bullet'"),
        (["check", "smol", "--physics", "mjx"], "--physics mjx needs --task"),
    ],
)
def test_the_command_line_refuses_a_bad_physics(tmp_path, monkeypatch, capsys, args, message):
    monkeypatch.chdir(tmp_path)
    code, err = cli(args, capsys)
    assert code == 2 and message in err and not list(tmp_path.iterdir())


def test_check_proves_a_schedule_against_the_ranges_of_the_physics(tmp_path, capsys):
    """A gear of 1e8 is within what walker2d takes on spring (finite up to 1.33e22) and beyond
    what it takes on MJX (7.5e7): `check --task` proves the one and refuses the other, located."""
    from smol_dsl.cli import main

    assert main(["check", "smol", "--task", "walker2d", "--physics", "mjx"]) == 0
    out = capsys.readouterr().out
    assert "walker2d on mjx takes these factors" in out and "smol.sched: ok" in out
    assert "gear: 1e-36 .. 7.5e+07 (where random policies' 1000-step rollouts on mjx stay finite" in out
    strong = tmp_path / "strong.sched"
    strong.write_text('name "strong"\n0% .. 90%: constant 1e8\n90% .. 100%: tail\n')
    assert main(["check", str(strong), "--task", "walker2d"]) == 0
    capsys.readouterr()
    code, err = cli(["check", str(strong), "--task", "walker2d", "--physics", "mjx"], capsys)
    assert code == 2 and f"{strong}:2:1: error: the gear factor may go up to 1e+08" in err
    assert "walker2d takes gear factors from 1e-36 to 7.5e+07" in err


def _runs_on_two_physics(root: Path, library: dict) -> list[Path]:
    """Two finished synthetic walker2d runs of one schedule, seeds 0 and 1: spring and MJX."""
    runs = []
    for seed, physics in enumerate(("spring", "mjx")):
        run = write_run(root / f"run-{physics}", library, "smol", seed, {"max_fitness": 10.0 + seed}, physics=physics)
        (run / ENVIRONMENT_FILE).write_text(environment_text(describe_environment([], physics=physics)))
        runs.append(run)
    return runs


def test_report_and_robustness_refuse_runs_of_two_physics_unless_allowed(tmp_path, library):
    _runs_on_two_physics(tmp_path, library)
    with pytest.raises(ReportError, match=r"not all produced under one environment: .*\(physics name mjx -> spring; "):
        load_runs([tmp_path])
    groups = load_runs([tmp_path], allow_mixed_environments=True)
    assert {name: [run.config.physics for run in runs] for name, runs in groups.items()} == {
        "SMOL on spring": ["spring"],
        "SMOL on mjx": ["mjx"],
    }


def test_a_report_across_physics_compares_each_schedule_on_each_physics_and_pools_none(tmp_path, library):
    """Asked to (--allow-mixed-environments), a report of runs on two physics groups them by
    schedule and physics, so that the same seed is in each and every test is between two
    conditions of one simulator each; robustness.csv measured one physics at a time joins
    under the report's names."""
    from smol_dsl.results.report import write_report
    from smol_dsl.results.robustness import robustness_for_report
    from smol_dsl.rundir import MEDIAN, RobustnessRow
    from smol_dsl.rundir.robustness import robustness_csv

    for physics in ("mjx", "spring"):
        for schedule in ("smol", "vanilla"):
            for seed in (0, 1, 2, 3):
                score = {
                    "max_fitness": 10.0 * seed + (100 if physics == "mjx" else 0) + (5 if schedule == "smol" else 0)
                }
                run = write_run(
                    tmp_path / physics / f"{schedule}-{seed}", library, schedule, seed, score, physics=physics
                )
                (run / ENVIRONMENT_FILE).write_text(environment_text(describe_environment([], physics=physics)))
    conditions = ["SMOL on spring", "SMOL on mjx", "Vanilla MAP-Elites on spring", "Vanilla MAP-Elites on mjx"]
    groups = load_runs([tmp_path], allow_mixed_environments=True)
    assert list(groups) == conditions and all(len(runs) == 4 for runs in groups.values())
    assert all({run.config.physics for run in groups[name]} == {name.rsplit(" ", 1)[1]} for name in conditions)
    written = write_report([tmp_path], tmp_path / "report", metric="max_fitness", allow_mixed_environments=True)
    table = (tmp_path / "report" / "table.md").read_text()
    assert "16 runs of walker2d: 2 schedules on spring and mjx x 4 seeds" in table
    assert "physics spring and mjx" in table
    (mixing,) = written.environment_mixing  # the 8 runs of the other physics differ alike: one sentence
    assert "(and 7 other runs alike) was started under another environment than" in mixing
    assert "physics name spring -> mjx" in mixing and table.count("physics name spring -> mjx") == 1
    assert list(written.table.pvalues) == conditions  # every condition a row and a column: no paper columns
    assert written.comparison is None and not (tmp_path / "report" / "paper-comparison.md").exists()
    assert written.table.pvalues["SMOL on spring"]["SMOL on mjx"] < 0.05  # 100 apart, by physics

    def rows(physics: str) -> list[RobustnessRow]:  # as `robustness` of one physics' runs names them
        measured = []
        for run in [run for name in conditions if name.endswith(physics) for run in groups[name]]:
            for sample in ("x1", MEDIAN):
                kept = 4 if physics == "spring" else 2  # each physics its own, to find in its condition
                counts = dict(samples=1, cells=4, filled=4, kept=kept, moved=4 - kept, collided=0, died=0)
                row = RobustnessRow(
                    str(run.directory),
                    run.schedule,
                    run.seed,
                    "body gear x1",
                    sample,
                    1.0,
                    **counts,
                    coverage=12.5,
                    max_fitness=1.0,
                )
                measured.append(row)
        return measured

    for physics in ("mjx", "spring"):
        (tmp_path / physics / "robustness.csv").write_text(robustness_csv(rows(physics)))
    robustness = robustness_for_report([tmp_path / p / "robustness.csv" for p in ("mjx", "spring")], groups, "walker2d")
    assert robustness.schedules == conditions
    assert {row.schedule for row in robustness.rows} == set(conditions)
    assert robustness.per_seed("body gear x1", MEDIAN, "kept") == {
        name: dict.fromkeys(range(4), 4.0 if name.endswith("spring") else 2.0) for name in conditions
    }


def test_explore_refuses_runs_of_two_physics_unless_allowed(tmp_path, library):
    from smol_dsl.results.explorer import Explorer

    _runs_on_two_physics(tmp_path, library)
    with pytest.raises(
        ReportError, match=r"simulated on different physics \(mjx: .*run-mjx; spring: .*\).*--allow-mixed"
    ):
        Explorer([tmp_path], replay=None, cache=tmp_path / "cache")
    explorer = Explorer([tmp_path], replay=None, cache=tmp_path / "cache", allow_mixed_environments=True)
    try:
        labels = [run["label"] for run in explorer.run_list()]
        assert [run["physics"] for run in explorer.run_list()] == ["spring", "mjx"]  # in seed order
        assert "seed 1, on mjx (run-mjx)" in labels[1] and "seed 0 (run-spring)" in labels[0]
    finally:
        explorer.close()


def test_a_run_is_not_resumed_on_another_physics(tmp_path, monkeypatch, capsys, library):
    monkeypatch.chdir(tmp_path)
    write_run(tmp_path / "run", library, "human", 0, {"max_fitness": 1.0}, finished=False)
    before = snapshot(tmp_path / "run")
    flags = ["--evals", "208", "--batch-size", "16", "--phases", "10", "--centroids", "32", "--episode-length", "20"]
    code, err = cli(["run", "walker2d", "human", *flags, "--out", "run", "--resume", "--physics", "mjx"], capsys)
    assert code == 2 and "--physics" in err and "spring" in err, err
    after = snapshot(tmp_path / "run")
    assert {name: data for name, data in after.items() if name != LOCK_FILE} == before


def test_robustness_on_another_physics_refuses_what_it_cannot_measure(tmp_path, library):
    """`--other-physics` re-scores on a physics the run did not train on, whose ranges take
    the run's final body; names are checked before any run is read."""
    from smol_dsl import parse
    from smol_dsl.rescoring.perturbations import (
        Perturbations,
        RobustnessError,
        check_families,
        check_perturbations,
    )
    from smol_dsl.rundir import read_run

    strong = parse('name "strong"\nfinal 1e8\n0% .. 90%: constant 1e8\n90% .. 100%: tail\n')  # not on MJX
    run = read_run(write_run(tmp_path / "strong", {**library, "strong": strong}, "strong", 0, {"max_fitness": 1.0}))
    spring = read_run(write_run(tmp_path / "spring", library, "smol", 0, {"max_fitness": 1.0}))
    only = dict(bodies=(), starts=0, float_path=False)
    check_perturbations([spring], Perturbations(**only, physics=("mjx",)))  # the final body of SMOL: x1
    assert Perturbations(**only, physics=("mjx",)).names == ["physics mjx"]
    for perturbations, runs, message in [
        (Perturbations(**only, physics=("spring",)), [spring], "trained on spring already"),
        (
            Perturbations(**only, physics=("mjx",)),
            [run],
            r"final body on mjx: thigh_joint.s gear factor would be 1e\+08, above",
        ),
    ]:
        with pytest.raises(RobustnessError, match=message):
            check_perturbations(runs, perturbations)
    for physics, message in [
        ("mjx", "a sequence of physics names"),
        (("mjx", "mjx"), "given twice"),
        (("x",), "unknown"),
    ]:
        with pytest.raises(RobustnessError, match=message):
            check_families(Perturbations(**only, physics=physics))


def test_mjx_on_a_cpu_with_several_runs_per_step_is_warned_of_the_known_hang(tmp_path, monkeypatch, capsys):
    """docs/scaling.md's known hang: the note comes before anything compiles, and only where
    a CPU device would advance several MJX runs at once under a jaxlib that hangs there."""
    from smol_dsl.runner import sweep as runner_sweep

    monkeypatch.chdir(tmp_path)
    sweep = ["sweep", "walker2d", "vanilla", "--seeds", "2", "--dry-run", "--no-measure", "--devices", "1"]
    monkeypatch.setattr(runner_sweep, "jaxlib_version", lambda: (0, 10, 2))
    code, err = cli([*sweep, "--physics", "mjx", "--runs-per-step", "2"], capsys)
    assert code == 0 and "note: MJX on a CPU with several runs per step hangs under jaxlib 0.10.2" in err
    assert "use the default, one run at a time, or jax 0.12 or later" in err
    for others in (["--physics", "mjx"], ["--runs-per-step", "2"]):  # one at a time; spring
        code, err = cli([*sweep, *others], capsys)
        assert code == 0 and "hang" not in err, others
    monkeypatch.setattr(runner_sweep, "jaxlib_version", lambda: (0, 12, 0))
    code, err = cli([*sweep, "--physics", "mjx", "--runs-per-step", "2"], capsys)
    assert code == 0 and "hang" not in err
    assert runner_sweep.MJX_CPU_HANG_FIXED == (0, 12)


# -- MJX's fields, and what each channel changes (real MJX physics) ---------------------------


@pytest.fixture(scope="module")
def mjx_walker():
    return make_task("walker2d", episode_length=20, physics="mjx")


def test_mjx_builds_the_tasks_for_mjx_jax_and_a_model_for_warp_is_refused(mjx_walker):
    """What environment.json records as MJX's implementation is the built model's; a model
    MJX built for Warp (MJX_GPU_DEFAULT_WARP=true on an NVIDIA GPU with warp-lang) is refused
    with what to do, before anything runs."""
    assert mjx_walker.env.sys.impl.value == MJX_IMPLEMENTATION == physics_record("mjx")["implementation"]
    with pytest.raises(UserInputError, match=r"'warp' implementation.*unset MJX_GPU_DEFAULT_WARP"):
        check_mjx_implementation("warp")


@pytest.mark.slow
def test_a_body_of_ones_on_mjx_is_the_model_itself_bit_for_bit(mjx_walker):
    """The modulated model equals the model, field by field, and so does a rollout: the task
    in a body of ones, and the same task with a hook that leaves the model alone."""
    import dataclasses

    import jax
    import jax.numpy as jnp

    task = mjx_walker.with_channels(CHANNELS)
    sys, changed = task.env.sys, task.modulate(task.env.sys, jnp.ones(4))
    for field in ("actuator_gear", "body_mass", "body_inertia", "body_invweight0", "dof_invweight0"):
        np.testing.assert_array_equal(getattr(changed, field), getattr(sys, field), err_msg=field)
    np.testing.assert_array_equal(changed.geom_friction, sys.geom_friction)
    np.testing.assert_array_equal(changed.opt.gravity, sys.opt.gravity)
    unscheduled = dataclasses.replace(task, modulation=lambda anatomy, channels: lambda sys, body: sys)
    params = task.init_policies(jax.random.key(1), 4)
    start = task.episode_start(0)
    ours = task.scoring_fn()(params, jnp.ones(4), start)
    theirs = unscheduled.scoring_fn()(params, jnp.ones(4), start)
    for a, b in zip(ours, theirs, strict=True):
        np.testing.assert_array_equal(a, b)
    assert np.all(np.isfinite(ours[0])) and np.ptp(np.asarray(ours[0])) > 0


@pytest.mark.slow
def test_each_channel_changes_what_mjx_reads(mjx_walker):
    """One step of the same action from the same start, in bodies that differ in one channel:
    gear 2 doubles every joint's actuator force; friction 0.5 halves every contact's
    coefficients; gravity 2 adds one g to the falling torso's acceleration; mass 2 slows the
    joints, and mass 2 with gear 2 nearly restores them (only the joints' armature and
    damping, which do not scale, keep it from exact)."""
    import jax
    import jax.numpy as jnp

    from smol_dsl.tasks.base import with_sys

    task = mjx_walker.with_channels(CHANNELS)
    start = task.episode_start(0)
    action = jnp.full((task.env.action_size,), 0.5)

    @jax.jit
    def step(body):
        state = with_sys(task.env, task.modulate(task.env.sys, body)).step(start, action).pipeline_state
        return state.qfrc_actuator, state.qacc, state.contact.friction

    def at(gear=1.0, mass=1.0, friction=1.0, gravity=1.0):
        return [np.asarray(x) for x in step(jnp.asarray([gear, mass, friction, gravity], jnp.float32))]

    base = at()
    np.testing.assert_array_equal(at(gear=2)[0], 2 * base[0])
    np.testing.assert_array_equal(at(friction=0.5)[2], 0.5 * base[2])
    rootz = 1  # walker2d's joints: rootx, rootz, rooty, then the legs'
    gravity = float(-np.asarray(task.env.sys.opt.gravity)[2])
    assert at(gravity=2)[1][rootz] == pytest.approx(base[1][rootz] - gravity, rel=1e-4)
    heavy, balanced = at(mass=2)[1][3:], at(mass=2, gear=2)[1][3:]
    assert np.linalg.norm(balanced - base[1][3:]) < 0.25 * np.linalg.norm(heavy - base[1][3:])


@pytest.mark.slow
@pytest.mark.parametrize("environment", ["walker2d", "ant"])
def test_the_inverse_weights_of_a_heavier_body_are_mujocos(environment):
    """MJX reads the inverse weights MuJoCo derives when it compiles a model; for a body whose
    links are each scaled by their own factor they are MuJoCo's own (`mj_setConst` on the
    model with those masses and inertias), to float32 rounding."""
    import brax
    import jax.numpy as jnp
    import mujoco
    from brax.io import mjcf

    from smol_dsl.tasks.mjx_body import scale_mass
    from smol_dsl.tasks.quiet import brax_environment

    sys = brax_environment(environment, backend="mjx").sys
    model = mjcf.load_mjmodel(os.path.join(os.path.dirname(brax.__file__), "envs", "assets", f"{environment}.xml"))
    factors = np.random.default_rng(0).uniform(0.3, 3.0, model.nbody - 1)
    model.body_mass[1:] *= factors
    model.body_inertia[1:] *= factors[:, None]
    mujoco.mj_setConst(model, mujoco.MjData(model))
    ours = scale_mass(sys, jnp.asarray(factors, jnp.float32))
    np.testing.assert_allclose(ours.body_invweight0, model.body_invweight0, rtol=2e-5)
    np.testing.assert_allclose(ours.dof_invweight0, model.dof_invweight0, rtol=2e-5)
    assert not np.allclose(ours.dof_invweight0, sys.dof_invweight0, rtol=0.05)  # they did change


@pytest.mark.slow
def test_the_feet_touch_the_same_ground_on_both_physics(mjx_walker):
    """The feet-contact descriptor reads each physics' contacts alike: at the episode start
    both list the same pairs (the floor with the torso and each foot) at the same distances."""
    spring = make_task("walker2d", episode_length=20)
    ours, theirs = mjx_walker.episode_start(0).pipeline_state, spring.episode_start(0).pipeline_state
    np.testing.assert_array_equal(ours.contact.link_idx[1], theirs.contact.link_idx[1])
    np.testing.assert_allclose(ours.contact.dist, theirs.contact.dist, atol=1e-6)
    np.testing.assert_array_equal(mjx_walker.state_descriptor(mjx_walker.episode_start(0)), [0.0, 0.0])


# -- a run on MJX: trains, resumes bit for bit, replays, reports ------------------------------


@pytest.fixture(scope="module")
def mjx_run(tmp_path_factory, library):
    """`run --physics mjx` of human at the tests' size: (its directory, its result)."""
    from small_runs import small_config

    from smol_dsl.runner import run_experiment

    out = tmp_path_factory.mktemp("mjx") / "whole"
    return out, run_experiment("walker2d", library["human"], small_config(physics="mjx"), out_dir=out)


@pytest.mark.slow
def test_a_run_on_mjx_resumes_bit_for_bit_replays_its_elites_and_reports(mjx_run, tmp_path, library):
    """`run --physics mjx` at the tests' size, interrupted after a few phases and resumed, ends
    exactly as the same run uninterrupted (the engines are one: compiled once); its records
    name MJX; every elite replays to the archive bit for bit on MJX (a replay on spring would
    not); the report says which physics ran."""
    from small_runs import small_config
    from test_replay import replays_bit_for_bit

    from smol_dsl.results.report import write_report
    from smol_dsl.runner import run_experiment

    config = small_config(physics="mjx")
    directory, whole = mjx_run
    run_experiment("walker2d", library["human"], config, out_dir=tmp_path / "cut", stop_after_generation=6)
    resumed = run_experiment("walker2d", library["human"], config, out_dir=tmp_path / "cut", resume=True)
    assert resumed.metrics == whole.metrics and whole.final["coverage"] > 0
    for name in ("metrics.csv", "phases.npz", "config.json"):
        assert (tmp_path / "cut" / name).read_bytes() == (directory / name).read_bytes(), name
    ours, theirs = np.load(tmp_path / "cut" / "archive.npz"), np.load(directory / "archive.npz")
    for name in theirs.files:
        np.testing.assert_array_equal(ours[name], theirs[name])
    assert read_config(directory / "config.json").physics == "mjx"
    environment = json.loads((directory / ENVIRONMENT_FILE).read_text())["environment"]
    assert environment["physics"]["name"] == "mjx"
    assert replays_bit_for_bit(directory) > 1
    written = write_report([directory], tmp_path / "report", gaits=0)
    assert "physics mjx" in (tmp_path / "report" / "table.md").read_text()
    assert "physics mjx (paper: spring)" in written.comparison.summary()


@pytest.mark.slow
def test_an_mjx_archive_re_scored_on_spring_is_what_spring_scores_it(mjx_run):
    """`robustness --other-physics spring` on an MJX run: every elite in its final body, from
    its seed's start, on spring, accounted for once; the same elites scored by spring's task
    itself (its `scoring_fn`: another program than the runner's, so equal within rounding)
    fill, keep and lose the same cells, and spring scores them otherwise than MJX did."""
    import jax

    from smol_dsl.rescoring.perturbations import Perturbations
    from smol_dsl.rescoring.robustness import measure_robustness, reinserted
    from smol_dsl.rundir import MEDIAN, load_archive, read_run
    from smol_dsl.runner.engine import shared_task

    directory, _ = mjx_run
    run, archive = read_run(directory), load_archive(directory)
    rows = measure_robustness([run], Perturbations(bodies=(), starts=0, float_path=False, physics=("spring",)))
    assert [(row.perturbation, row.sample, row.samples) for row in rows] == [
        ("physics spring", "on spring", 1),
        ("physics spring", MEDIAN, 1),
    ]
    sample = rows[0]
    cells = np.flatnonzero(archive.filled)
    assert sample.kept + sample.moved + sample.collided + sample.died == sample.cells == len(cells) > 1

    config = run.config
    spring = shared_task("walker2d", config.episode_length, tuple(config.hidden_layer_sizes), "spring")
    spring = spring.with_channels(run.channels)
    genotypes = jax.tree.map(lambda leaf: np.asarray(leaf)[cells], archive.genotypes)
    body = np.asarray(run.phase_bodies()[-1], np.float32)
    scored, described = spring.scoring_fn()(genotypes, body, spring.episode_start(config.seed))
    fitnesses = np.full(len(archive.filled), -np.inf, np.float32)
    descriptors = np.zeros_like(np.asarray(archive.descriptors, np.float32))
    fitnesses[cells], descriptors[cells] = np.asarray(scored), np.asarray(described)
    holder, best = reinserted(archive.centroids, fitnesses, descriptors)
    filled = best > -np.inf
    assert (sample.filled, sample.kept) == (int(filled.sum()), int(np.sum(filled & (holder == np.arange(len(holder))))))
    assert sample.max_fitness == pytest.approx(float(best.max()), rel=1e-4)
    assert not np.allclose(np.asarray(scored), np.asarray(archive.fitnesses)[cells], rtol=1e-3)  # another physics
