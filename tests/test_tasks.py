"""The alpha-aware Brax tasks: QDax parity at alpha = 1, gear scaling, one compilation, the registry."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from qdax_reference import qdax_scores

from smol_dsl.tasks import TaskSpec, make_task, register, task_names, task_spec
from smol_dsl.tasks.base import deterministic_init_state
from smol_dsl.tasks.body import scale_gear

EPISODE = 50  # the episodes of conftest's walker and cheetah
BATCH = 8


def qdax_start(task):
    """The episode start QDax's scoring function uses for key 3."""
    return deterministic_init_state(task.env, jax.random.key(3))


def _qdax_scores(qdax_name, task, params, gear_scale=None, feet=None):
    """QDax's scoring (qdax_reference); with `gear_scale`, in the plain Brax env with its
    actuators' gear multiplied; with `feet`, QDax's feet-contact wrapper told which links are the feet."""

    def scaled(sys):
        return sys.replace(actuator=sys.actuator.replace(gear=sys.actuator.gear * gear_scale))

    edit = None if gear_scale is None else scaled
    return qdax_scores(qdax_name, task, params, episode_length=EPISODE, edit=edit, feet=feet)


@pytest.mark.parametrize(("fixture", "qdax_name"), [("walker", "walker2d_uni"), ("cheetah", "halfcheetah_uni")])
@pytest.mark.slow
def test_alpha_one_equals_qdax_uni_task(request, fixture, qdax_name):
    task = request.getfixturevalue(fixture)
    params = task.init_policies(jax.random.key(1), BATCH)
    fitnesses, descriptors = task.scoring_fn()(params, jnp.array([1.0]), qdax_start(task))
    expected_fitnesses, expected_descriptors = _qdax_scores(qdax_name, task, params)
    np.testing.assert_allclose(np.asarray(fitnesses), expected_fitnesses, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(descriptors), expected_descriptors, atol=1e-6)
    assert descriptors.shape == (BATCH, 2)


@pytest.mark.slow
def test_hopper_at_alpha_one_equals_qdax_hopper_uni():
    task = make_task("hopper", episode_length=EPISODE)
    params = task.init_policies(jax.random.key(1), BATCH)
    fitnesses, descriptors = task.scoring_fn()(params, jnp.array([1.0]), qdax_start(task))
    expected_fitnesses, expected_descriptors = _qdax_scores("hopper_uni", task, params)
    np.testing.assert_allclose(np.asarray(fitnesses), expected_fitnesses, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(descriptors), expected_descriptors, atol=1e-6)
    assert descriptors.shape == (BATCH, 1) and len(set(np.asarray(descriptors)[:, 0])) > 1


@pytest.mark.slow
def test_ant_uni_at_alpha_one_equals_qdax_ant_uni_with_the_lower_legs_as_feet():
    """QDax 0.5's ant_uni looks for Brax v1's feet ("$ Body 4", ...), which Brax v2's ant lacks
    (its lower legs are unnamed links), so its descriptors are empty: the test gives QDax's
    feet-contact wrapper the four lower legs. Fitness is Brax's ant reward, as QDax's."""
    task = make_task("ant_uni", episode_length=EPISODE, hidden_layer_sizes=(64, 64))
    lower_legs = [i for i, name in enumerate(task.spec.anatomy.links) if name.startswith("lower_leg_")]
    assert lower_legs == [2, 4, 6, 8] and [task.env.sys.link_names[i] for i in lower_legs] == [""] * 4
    params = task.init_policies(jax.random.key(1), BATCH)
    fitnesses, descriptors = task.scoring_fn()(params, jnp.array([1.0]), qdax_start(task))
    expected_fitnesses, expected_descriptors = _qdax_scores("ant_uni", task, params, feet=lower_legs)
    np.testing.assert_allclose(np.asarray(fitnesses), expected_fitnesses, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(descriptors), expected_descriptors, atol=1e-6)
    assert descriptors.shape == (BATCH, 4) and np.ptp(np.asarray(descriptors)) > 0


@pytest.mark.parametrize("alpha", [0.5, 1.5])
@pytest.mark.slow
def test_alpha_equals_plain_brax_env_with_scaled_gear(walker, alpha):
    params = walker.init_policies(jax.random.key(2), BATCH)
    fitnesses, descriptors = walker.scoring_fn()(params, jnp.array([alpha]), qdax_start(walker))
    expected_fitnesses, expected_descriptors = _qdax_scores("walker2d_uni", walker, params, gear_scale=alpha)
    np.testing.assert_allclose(np.asarray(fitnesses), expected_fitnesses, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(np.asarray(descriptors), expected_descriptors, atol=1e-6)


@pytest.mark.slow
def test_alpha_changes_the_physics_without_recompiling(walker):
    params = walker.init_policies(jax.random.key(4), BATCH)
    score = walker.scoring_fn()
    start = walker.episode_start(0)
    results = [np.asarray(score(params, jnp.array([alpha]), start)[0]) for alpha in (0.6, 1.0, 1.4)]
    assert score._cache_size() == 1
    assert not np.allclose(results[0], results[2])


@pytest.mark.slow
def test_ant_omni_scores_final_position_and_energy():
    task = make_task("ant_omni", episode_length=20, hidden_layer_sizes=(16, 16))
    params = task.init_policies(jax.random.key(0), 4)
    fitnesses, descriptors = task.scoring_fn()(params, jnp.array([1.2]), task.episode_start(0))
    assert descriptors.shape == (4, 2) and fitnesses.shape == (4,)
    assert np.all(np.isfinite(fitnesses)) and np.all(np.abs(np.asarray(descriptors)) <= 30.0)
    # fitness is the healthy bonus minus control and contact costs: at most 1 per step
    assert np.all(np.asarray(fitnesses) <= 20.0)


def test_policies_are_tanh_mlps_with_the_papers_sizes(walker):
    params = walker.init_policies(jax.random.key(0), 1)
    kernels = [v["kernel"].shape for v in params["params"].values()]
    assert kernels == [(1, 17, 64), (1, 64, 64), (1, 64, 6)]
    assert walker.policy.activation is jnp.tanh and walker.policy.final_activation is jnp.tanh


def test_unknown_task():
    with pytest.raises(ValueError, match="walker2d, halfcheetah, ant_omni, hopper, ant_uni"):
        make_task("unicycle")
    with pytest.raises(ValueError, match="unknown task 'unicycle'"):
        task_spec("unicycle")


def test_every_spec_is_complete_and_matches_its_task():
    from smol_dsl.runner.config import preset_config

    for name in task_names():
        spec = task_spec(name)
        assert spec.help and spec.default_metric in ("max_fitness", "coverage", "qd_score")
        for preset in ("quick", "paper"):
            assert preset_config(name, preset).batch_size == spec.presets[preset]["batch_size"]
        task = make_task(name, episode_length=5, hidden_layer_sizes=(4,))
        assert task.spec is spec and task.descriptor_size == len(spec.descriptor_low)
        assert task.qd_offset == pytest.approx(spec.reward_offset * 5)


def test_the_episode_start_comes_from_the_seed_alone(walker):
    other = make_task("walker2d", episode_length=EPISODE)
    for seed in (0, 7):
        a, b = walker.episode_start(seed), other.episode_start(seed)
        np.testing.assert_array_equal(np.asarray(a.obs), np.asarray(b.obs))
    assert not np.array_equal(np.asarray(walker.episode_start(0).obs), np.asarray(walker.episode_start(7).obs))


@pytest.mark.slow
def test_modulation_is_the_hook_that_changes_the_body(walker):
    """A task whose `modulation` scales the gear by 2 alpha equals the standard task at 2 alpha."""
    import dataclasses

    def doubled_gear(anatomy, channels):
        return lambda sys, body: scale_gear(sys, 2 * body[0])

    doubled = dataclasses.replace(walker, modulation=doubled_gear)
    params = walker.init_policies(jax.random.key(5), BATCH)
    start = walker.episode_start(0)
    expected = walker.scoring_fn()(params, jnp.array([1.2]), start)
    actual = doubled.scoring_fn()(params, jnp.array([0.6]), start)
    np.testing.assert_allclose(np.asarray(actual[0]), np.asarray(expected[0]), rtol=1e-5, atol=1e-5)


def test_a_task_registers_in_one_line_and_builds_lazily():
    spec = TaskSpec(
        name="walker2d_test_copy",
        help="walker2d under another name",
        environment="walker2d",
        factory="smol_dsl.tasks.feet:make",
        descriptor_low=(0.0, 0.0),
        descriptor_high=(1.0, 1.0),
        reward_offset=1.413,
        default_metric="coverage",
        presets=task_spec("walker2d").presets,
        details=task_spec("walker2d").details,
    )
    register(spec)
    assert "walker2d_test_copy" in task_names()
    assert make_task("walker2d_test_copy", episode_length=5, hidden_layer_sizes=(4,)).name == "walker2d_test_copy"
    with pytest.raises(ValueError, match="already registered"):
        register(dataclasses_replace(spec, help="another"))


def dataclasses_replace(spec, **changes):
    import dataclasses

    return dataclasses.replace(spec, **changes)


REGISTRY_PROBE = """
import sys
import smol_dsl.tasks, smol_dsl.runner.config
from smol_dsl.tasks import task_spec
task_spec("ant_omni").descriptor_high
print(sorted(m for m in ("jax", "brax", "qdax", "flax", "mujoco") if m in sys.modules))
"""


def test_the_registry_and_run_settings_import_no_jax_or_brax():
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", REGISTRY_PROBE], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "[]\n"


QUIET_PROBE = """
from smol_dsl.tasks import make_task
for name in ("walker2d", "halfcheetah", "ant_omni", "hopper", "ant_uni"):
    make_task(name, episode_length=5, hidden_layer_sizes=(4,))
print("built")
"""


@pytest.mark.slow
def test_no_warp_brax_or_mujoco_noise(tmp_path):
    """MJX's Warp import lines, Brax's maintenance warning and MuJoCo's MUJOCO_LOG.TXT stay out."""
    import os
    import subprocess
    import sys

    env = {key: value for key, value in os.environ.items() if key != "PYTHONWARNINGS"}
    done = subprocess.run(
        [sys.executable, "-W", "default", "-c", QUIET_PROBE], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout == "built\n"
    assert "warp" not in done.stderr.lower() and "not actively being maintained" not in done.stderr
    assert "settotalmass" not in done.stderr
    assert list(tmp_path.iterdir()) == []
