"""Bodies under several channels (tasks/body.py): real Brax rollouts against hand-edited systems."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from qdax_reference import qdax_scores

from smol_dsl.language.channels import GEAR, Channel
from smol_dsl.tasks import TASK_NAMES, make_task, task_spec
from smol_dsl.tasks.base import deterministic_init_state, with_sys
from smol_dsl.tasks.body import modulation, scale_gear

pytestmark = pytest.mark.slow  # every test here compiles Brax physics

EPISODE = 50  # the episodes of conftest's walker and cheetah
BATCH = 8
CHANNELS = tuple(
    Channel.parse(name)
    for name in (
        "gear",
        "gear[left_leg]",
        "gear[thigh_joint]",
        "mass",
        "mass[right_leg]",
        "mass[torso]",
        "friction",
        "gravity",
    )
)
LEFT_LEG_ACTUATORS = np.array([3, 4, 5])  # walker2d's thigh_left_joint, leg_left_joint, foot_left_joint


@pytest.fixture(scope="session")
def walker_body(walker):
    """walker2d under every kind of channel (one compilation for every test here)."""
    return walker.with_channels(CHANNELS)


def values(**changed: float) -> jax.Array:
    """The (C,) values of CHANNELS: 1 but for the channels named (`mass=2.0`, `gear_left_leg=0.5`)."""
    named = {channel.name.replace("[", "_").replace("]", "").replace(",", "_"): i for i, channel in enumerate(CHANNELS)}
    out = np.ones(len(CHANNELS), np.float32)
    for name, value in changed.items():
        out[named[name]] = value
    return jnp.asarray(out)


def start(task):
    """The episode start QDax's deterministic scoring uses for key 3."""
    return deterministic_init_state(task.env, jax.random.key(3))


def hand_edited_scores(task, params, edit):
    """QDax's walker2d_uni scoring of policies in a Brax env whose sys `edit` changed (reset in it)."""
    return qdax_scores("walker2d_uni", task, params, episode_length=EPISODE, edit=edit)


def heavier(k):
    """The body Brax simulates, k times as heavy and as hard to turn, edited by hand: its
    simulated masses m ** (1 - spring_mass_scale) and inertia diagonals written with scales 0."""

    def edit(sys):
        mass = np.asarray(sys.link.inertia.mass) ** (1 - float(sys.spring_mass_scale)) * k
        diagonal = np.diagonal(np.asarray(sys.link.inertia.i), axis1=1, axis2=2)
        diagonal = diagonal ** (1 - float(sys.spring_inertia_scale))
        return sys.tree_replace(
            {
                "link.inertia.mass": jnp.asarray(mass, jnp.float32),
                "link.inertia.i": jnp.asarray(np.einsum("li,ij->lij", diagonal * k, np.eye(3)), jnp.float32),
                "spring_mass_scale": 0.0,
                "spring_inertia_scale": 0.0,
            }
        )

    return edit


def slipperier(k):
    return lambda sys: sys.replace(geom_friction=sys.geom_friction * k)


def gravity_times(k):
    return lambda sys: sys.tree_replace({"gravity": sys.gravity * k, "opt.gravity": sys.opt.gravity * k})


def left_leg_gear_times(k):
    return lambda sys: sys.replace(
        actuator=sys.actuator.replace(gear=sys.actuator.gear.at[LEFT_LEG_ACTUATORS].multiply(k))
    )


def all_at_once(friction, gravity, left_leg):
    def edit(sys):
        return left_leg_gear_times(left_leg)(gravity_times(gravity)(slipperier(friction)(sys)))

    return edit


def test_every_task_anatomy_names_its_brax_sys():
    """Actuator i is named by the joint it drives; links follow sys.link_names (names Brax left
    empty excepted)."""
    assert len(TASK_NAMES) >= 5
    for name in TASK_NAMES:  # the bundled tasks: each has an anatomy
        plan = task_spec(name).anatomy
        sys = make_task(name, episode_length=5, hidden_layer_sizes=(4,)).env.sys
        model = sys.mj_model
        driven = tuple(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in model.actuator_trnid[:, 0])
        assert plan.actuators == driven, name
        assert sys.actuator.gear.shape == (len(plan.actuators),)
        assert len(plan.links) == len(sys.link_names) == sys.link.inertia.mass.shape[0], name
        for ours, brax in zip(plan.links, sys.link_names, strict=True):
            assert ours == brax or (brax == "" and ours), (name, ours, brax)
        for part in ("actuators", "links"):
            names = plan.names(part)
            assert len(set(names)) == len(names), (name, part)
            for group, members in plan.groups(part).items():
                assert group not in names and set(members) <= set(names), (name, group)


def test_ant_lower_legs_are_the_links_the_ankles_drive():
    sys = make_task("ant_uni", episode_length=5, hidden_layer_sizes=(4,)).env.sys
    plan, model = task_spec("ant_uni").anatomy, sys.mj_model
    for leg in "1234":
        link = plan.links.index(f"lower_leg_{leg}")
        assert sys.link_parents[link] == plan.links.index(f"aux_{leg}")
        ankle = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"ankle_{leg}")
        assert model.jnt_bodyid[ankle] == link + 1  # body = link + 1 (body 0 is the world)
    assert plan.indices(Channel("gear", ("front_left_leg",))) == (2, 3)  # hip_1, ankle_1


def test_the_gear_channel_is_scale_gear_bit_for_bit(walker):
    """Plain gear, the default body: its hook is `scale_gear` of the one factor, and scoring in
    body [1.3] equals scoring in a sys whose gear was scaled by hand, bit for bit."""
    import dataclasses

    assert walker.channels == (GEAR,) and walker.with_channels(["gear"]) is walker
    mine, theirs = walker.modulate(walker.env.sys, jnp.array([1.3])), scale_gear(walker.env.sys, jnp.float32(1.3))
    for a, b in zip(jax.tree.leaves(mine), jax.tree.leaves(theirs), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    by_hand = dataclasses.replace(walker, modulation=lambda anatomy, channels: lambda sys, body: theirs)
    params = walker.init_policies(jax.random.key(6), BATCH)
    expected = by_hand.scoring_fn()(params, jnp.ones(1), start(walker))
    actual = walker.scoring_fn()(params, jnp.array([1.3], jnp.float32), start(walker))
    for a, b in zip(actual, expected, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_at_one_every_channel_gives_the_plain_task(walker, walker_body):
    params = walker.init_policies(jax.random.key(7), BATCH)
    expected = walker.scoring_fn()(params, jnp.array([1.0]), start(walker))
    actual = walker_body.scoring_fn()(params, values(), start(walker))
    for a, b in zip(actual, expected, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize(
    ("changed", "edit"),
    [
        ({"mass": 1.6}, heavier(1.6)),
        ({"friction": 0.3, "gravity": 0.6, "gear_left_leg": 0.4}, all_at_once(0.3, 0.6, 0.4)),
    ],
    ids=["mass", "friction, gravity and gear[left_leg]"],
)
def test_a_channel_equals_a_hand_edited_brax_sys(walker, walker_body, changed, edit):
    params = walker.init_policies(jax.random.key(8), BATCH)
    fitnesses, descriptors = walker_body.scoring_fn()(params, values(**changed), start(walker))
    expected_fitnesses, expected_descriptors = hand_edited_scores(walker, params, edit)
    np.testing.assert_allclose(np.asarray(fitnesses), expected_fitnesses, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(np.asarray(descriptors), expected_descriptors, atol=1e-6)
    plain = np.asarray(walker.scoring_fn()(params, jnp.array([1.0]), start(walker))[0])
    assert np.abs(np.asarray(fitnesses) - plain).max() > 0.1  # the channel changed the physics


def test_values_are_traced(walker, walker_body):
    params = walker.init_policies(jax.random.key(9), BATCH)
    score = walker_body.scoring_fn()
    for v in (values(mass=0.7), values(friction=2.0, gravity=1.2), values(gear=1.3, mass_torso=1.5)):
        score(params, v, start(walker))
    assert score._cache_size() == 1


def test_factors_of_one_kind_multiply(walker_body):
    sys = walker_body.env.sys
    changed = walker_body.modulate(
        sys, values(gear=2.0, gear_left_leg=3.0, gear_thigh_joint=5.0, mass=2.0, mass_torso=3.0, gravity=0.5)
    )
    gear = np.asarray(sys.actuator.gear) * np.array([10, 2, 2, 6, 6, 6])
    np.testing.assert_allclose(np.asarray(changed.actuator.gear), gear, rtol=1e-6)
    links = np.array([6.0, 2, 2, 2, 2, 2, 2])  # the torso is under mass and mass[torso]
    np.testing.assert_allclose(
        np.asarray(changed.link.inertia.mass), np.asarray(sys.link.inertia.mass) * links, rtol=1e-6
    )
    # walker2d's spring pipeline simulates unit inertia (spring_inertia_scale 1): now written as such, times the factor
    assert float(sys.spring_inertia_scale) == 1.0 and float(changed.spring_inertia_scale) == 0.0
    np.testing.assert_allclose(np.asarray(changed.link.inertia.i), links[:, None, None] * np.eye(3))
    np.testing.assert_allclose(np.asarray(changed.gravity), np.asarray(sys.gravity) * 0.5)
    # the fields MJX reads are MJX's hook's to write (tasks.mjx_body): spring's leaves them alone
    for field in ("body_mass", "body_inertia", "actuator_gear", "body_invweight0"):
        np.testing.assert_array_equal(np.asarray(getattr(changed, field)), np.asarray(getattr(sys, field)))
    np.testing.assert_array_equal(np.asarray(changed.opt.gravity), np.asarray(sys.opt.gravity))
    np.testing.assert_array_equal(np.asarray(changed.geom_friction), np.asarray(sys.geom_friction))


def test_friction_scales_every_contact(walker_body):
    """Brax's contacts take the larger of the two geoms' coefficients (MJX's collision), so
    scaling every geom's scales every contact's by the factor."""
    from brax import contact, kinematics

    sys = walker_body.env.sys
    x, _ = kinematics.forward(sys, sys.init_q, jnp.zeros(sys.qd_size()))
    plain = contact.get(sys, x)
    scaled = contact.get(walker_body.modulate(sys, values(friction=0.25)), x)
    assert np.unique(np.asarray(plain.friction[:, 0])).size > 1  # the feet's coefficients differ
    np.testing.assert_array_equal(np.asarray(scaled.friction), np.asarray(plain.friction) * np.float32(0.25))


def test_a_body_under_friction_a_tenth_slips(walker_body):
    """Sliding forward at 2 m/s, actuators idle: the feet stop on the ground, or slide on at a tenth."""
    env = walker_body.env

    @jax.jit
    def foot_speeds(v: jax.Array) -> jax.Array:
        moved = with_sys(env, walker_body.modulate(env.sys, v))
        state = moved.pipeline_init(env.sys.init_q, jnp.zeros(env.sys.qd_size()).at[0].set(2.0))

        def step(state, _):
            state = moved.pipeline_step(state, jnp.zeros(env.action_size))
            return state, state.xd.vel[env.sys.link_names.index("foot"), 0]

        return jax.lax.scan(step, state, None, length=40)[1][-15:]

    assert np.abs(np.asarray(foot_speeds(values()))).mean() < 0.5
    assert np.abs(np.asarray(foot_speeds(values(friction=0.1)))).mean() > 1.5


def test_heavier_links_keep_their_mass_from_the_first_step(walker, walker_body):
    """The spring pipeline keeps the masses it computed at reset: the rollout gives the start the
    changed body's, or a heavier walker would move as the plain one until the end."""
    params = walker.init_policies(jax.random.key(10), BATCH)
    heavy = walker_body.scoring_fn()(params, values(mass_right_leg=3.0), start(walker))[0]
    plain = walker.scoring_fn()(params, jnp.array([1.0]), start(walker))[0]
    assert not np.allclose(np.asarray(heavy), np.asarray(plain))


def test_channels_the_body_cannot_take_are_refused(walker):
    with pytest.raises(ValueError, match="gear\\[tail\\]: cannot select tail; actuators: thigh_joint"):
        walker.with_channels(["gear[tail]"])
    with pytest.raises(ValueError, match="friction takes no targets: it scales the friction of every contact"):
        walker.with_channels(["friction[foot]"])
    with pytest.raises(ValueError, match="no channels"):
        walker.with_channels([])
    with pytest.raises(ValueError, match="anatomy has 6 actuators and 7 links"):
        modulation(task_spec("walker2d").anatomy, (GEAR,))(make_task("hopper", episode_length=5).env.sys, jnp.ones(1))


def test_mass_changes_a_body_brax_simulates_with_unit_masses():
    """Hopper's spring pipeline gives every link mass 1 and unit inertia whatever sys says;
    the mass channel scales what is simulated, so a heavier hopper moves differently, and at
    1 the hopper is the plain one. (The plain hopper is test_tasks' at EPISODE, BATCH and the
    paper's policy sizes: one program, compiled once in the session and loaded by the other.)"""
    hopper = make_task("hopper", episode_length=EPISODE)
    assert float(hopper.env.sys.spring_mass_scale) == 1.0 == float(hopper.env.sys.spring_inertia_scale)
    body = hopper.with_channels(["gear", "mass[whole_leg]", "friction", "gravity"])
    params = hopper.init_policies(jax.random.key(11), BATCH)
    plain = hopper.scoring_fn()(params, jnp.ones(1), start(hopper))
    at_one = body.scoring_fn()(params, jnp.ones(4), start(hopper))
    for a, b in zip(at_one, plain, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    heavy = body.scoring_fn()(params, jnp.asarray([1.0, 3.0, 1.0, 1.0]), start(hopper))[0]
    assert np.abs(np.asarray(heavy) - np.asarray(plain[0])).max() > 0.1
    sys = body.modulate(hopper.env.sys, jnp.asarray([1.0, 3.0, 1.0, 1.0]))
    np.testing.assert_array_equal(np.asarray(sys.link.inertia.mass), [1.0, 3.0, 3.0, 3.0])  # torso unscheduled


def test_a_task_with_its_own_modulation_gets_every_body(walker):
    """A task's own `modulation` (here, the standard hook on a sys with twice the gear) makes
    the hook of whatever channels the task is put under."""
    import dataclasses

    def doubled(anatomy, channels):
        standard = modulation(anatomy, channels)
        return lambda sys, body: standard(scale_gear(sys, 2.0), body)

    body = dataclasses.replace(walker, modulation=doubled).with_channels(["gear", "gravity"])
    sys = body.modulate(walker.env.sys, jnp.asarray([0.5, 0.5]))
    np.testing.assert_allclose(np.asarray(sys.actuator.gear), np.asarray(walker.env.sys.actuator.gear))
    np.testing.assert_allclose(np.asarray(sys.gravity), np.asarray(walker.env.sys.gravity) * 0.5)
