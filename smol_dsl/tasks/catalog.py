"""The bundled tasks' specs: QDax's locomotion tasks, sized as in the paper.

Presets: "paper" is the paper's table of hyperparameters per task (its 1e7 evaluations,
100 phases and 1024 cells are common to all, in smol_dsl.rundir.presets; hopper and ant_uni,
which the paper does not run, are sized as its uni tasks, with QDax's usual (64, 64)
network); "quick" is sized so that a run takes a few minutes on 2 CPU cores. Raw rollouts
(`scoring_fn` after compilation, the quick batch, 100 steps, one XLA device on 2 shared
cores) run at about 410 walker2d evaluations/s (batch 128), 90 halfcheetah (64), 145
ant_omni (64), 640 hopper (128) and 155 ant_uni (64): a quick preset's evaluations take
1.5 to 3 minutes of raw rollouts.

Factor ranges: each task states, per physics and kind of channel, the factors its physics takes
(`tasks.ranges`): those at which `benchmarks/factor_ranges.py` found every rollout of 16
random policies finite (the paper's episode length, 1000 steps, 100 for ant_omni), on a grid
of 8 factors per decade from 1e-36 to 1e36, so each stated end lies within a factor 1.34 of
the first factor that failed. Brax's spring pipeline simulates most bodies far beyond sense
without overflowing: what breaks it is a gear or a gravity so large that the state
overflows, or a body so light that its links' accelerations do (halfcheetah below 0.2 of its
mass, the ants below about 0.02). On MJX (`--physics mjx`, the same search) the ranges are
narrower: walker2d and hopper are finite up to gear 7.5e7 and 1.78e8 and gravity 2.37e15 and
5.62e13, at any mass or friction (MJX's inverse weights follow the mass); ant_omni (100 steps)
and ant_uni up to gear 4.22e3 and 7.5e3 and gravity 1.78e5, friction from 0.00237;
halfcheetah only up to gear 5.62 and gravity 750, mass from 1e-15 to 1.78e33, friction from
0.0133.
"""

from __future__ import annotations

from smol_dsl.language.float32_limits import SAFE_MAX, SAFE_MIN
from smol_dsl.tasks.anatomy import Anatomy
from smol_dsl.tasks.ranges import FactorRange
from smol_dsl.tasks.registry import TaskSpec

DUTY_FACTORS = ((0.0, 0.0), (1.0, 1.0))  # two feet, each in contact a proportion of the steps


def measured(episode_length: int, physics: str = "spring", **finite: tuple[float, float]) -> dict[str, FactorRange]:
    """Each kind's stated range on `physics`: the factors (low, high) at which every rollout of
    `benchmarks/factor_ranges.py` stayed finite, within float32's safe range."""
    on = "" if physics == "spring" else f" on {physics}"
    how = "benchmarks/factor_ranges.py" + ("" if physics == "spring" else f" --physics {physics}")
    return {
        kind: FactorRange(
            max(low, SAFE_MIN),
            min(high, SAFE_MAX),
            f"where random policies' {episode_length}-step rollouts{on} stay finite, {how}",
        )
        for kind, (low, high) in finite.items()
    }


WALKER2D = TaskSpec(
    name="walker2d",
    help="Walker2d, run forward; descriptor: each foot's duty factor (QDax walker2d_uni)",
    environment="walker2d",
    factory="smol_dsl.tasks.feet:make",
    descriptor_low=DUTY_FACTORS[0],
    descriptor_high=DUTY_FACTORS[1],
    reward_offset=1.413,  # QDax's, for walker2d_uni
    default_metric="max_fitness",
    presets={
        "paper": dict(batch_size=8192, episode_length=1000, hidden_layer_sizes=(64, 64)),
        "quick": dict(batch_size=128, episode_length=100, evaluations=65_536, hidden_layer_sizes=(64, 64)),
    },
    details={"feet": ("foot", "foot_left")},
    factor_ranges={
        "spring": measured(
            1000, gear=(1e-36, 1.33e22), mass=(7.5e-8, 1e36), friction=(1e-36, 1e36), gravity=(1e-36, 3.16e23)
        ),
        "mjx": measured(
            1000, "mjx", gear=(1e-36, 7.5e7), mass=(1e-36, 1e36), friction=(1e-36, 1e36), gravity=(1e-36, 2.37e15)
        ),
    },
    observation_size=17,  # the policy's input (a test builds the task and checks it)
    step_seconds=0.008,  # the env's dt (checked alike)
    anatomy=Anatomy(
        actuators=("thigh_joint", "leg_joint", "foot_joint", "thigh_left_joint", "leg_left_joint", "foot_left_joint"),
        links=("torso", "thigh", "leg", "foot", "thigh_left", "leg_left", "foot_left"),
        actuator_groups={
            "right_leg": ("thigh_joint", "leg_joint", "foot_joint"),
            "left_leg": ("thigh_left_joint", "leg_left_joint", "foot_left_joint"),
        },
        link_groups={"right_leg": ("thigh", "leg", "foot"), "left_leg": ("thigh_left", "leg_left", "foot_left")},
    ),
)

HALFCHEETAH = TaskSpec(
    name="halfcheetah",
    help="HalfCheetah, run forward; descriptor: each foot's duty factor (QDax halfcheetah_uni)",
    environment="halfcheetah",
    factory="smol_dsl.tasks.feet:make",
    descriptor_low=DUTY_FACTORS[0],
    descriptor_high=DUTY_FACTORS[1],
    reward_offset=9.231,  # QDax's, for halfcheetah_uni
    default_metric="max_fitness",
    presets={
        "paper": dict(batch_size=8192, episode_length=1000, hidden_layer_sizes=(64, 64)),
        "quick": dict(batch_size=64, episode_length=100, evaluations=8_192, hidden_layer_sizes=(64, 64)),
    },
    details={"feet": ("bfoot", "ffoot")},
    factor_ranges={
        "spring": measured(
            1000, gear=(1e-36, 2.37e18), mass=(0.237, 1e36), friction=(1e-36, 1e36), gravity=(1e-36, 1.78e7)
        ),
        "mjx": measured(
            1000, "mjx", gear=(1e-36, 5.62), mass=(1e-15, 1.78e33), friction=(0.0133, 1.33e35), gravity=(1e-36, 750)
        ),
    },
    observation_size=17,  # the policy's input (a test builds the task and checks it)
    step_seconds=0.05,  # the env's dt (checked alike)
    anatomy=Anatomy(
        actuators=("bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot"),
        links=("torso", "bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot"),
        actuator_groups={"back_leg": ("bthigh", "bshin", "bfoot"), "front_leg": ("fthigh", "fshin", "ffoot")},
        link_groups={"back_leg": ("bthigh", "bshin", "bfoot"), "front_leg": ("fthigh", "fshin", "ffoot")},
    ),
)

# Brax's ant: leg i is hip_i (the link aux_i) then ankle_i (a link Brax leaves unnamed,
# here lower_leg_i, whose sphere is the foot). The legs are named by where they are, +x
# being forward (the x velocity is the reward): leg 1 at (+x, +y) is the front left one.
# ant.xml's own body names for legs 2 and 4 (front_right_leg, right_back_leg) disagree.
ANT_LEGS = {"front_left_leg": "1", "back_left_leg": "2", "back_right_leg": "3", "front_right_leg": "4"}
ANT_ANATOMY = Anatomy(
    actuators=("hip_4", "ankle_4", "hip_1", "ankle_1", "hip_2", "ankle_2", "hip_3", "ankle_3"),
    links=("torso", *(name for i in "1234" for name in (f"aux_{i}", f"lower_leg_{i}"))),
    actuator_groups={leg: (f"hip_{i}", f"ankle_{i}") for leg, i in ANT_LEGS.items()},
    link_groups={leg: (f"aux_{i}", f"lower_leg_{i}") for leg, i in ANT_LEGS.items()},
)

ANT_OMNI = TaskSpec(
    name="ant_omni",
    help="Ant, reach anywhere; descriptor: final (x, y); fitness: minus the energy used (QDax ant_omni)",
    environment="ant",
    factory="smol_dsl.tasks.ant_omni:make",
    descriptor_low=(-30.0, -30.0),
    descriptor_high=(30.0, 30.0),
    reward_offset=3.0,  # QDax's, for ant_omni
    default_metric="coverage",
    presets={
        "paper": dict(batch_size=1024, episode_length=100, hidden_layer_sizes=(256, 256)),
        "quick": dict(batch_size=64, episode_length=100, evaluations=12_800, hidden_layer_sizes=(256, 256)),
    },
    factor_ranges={
        "spring": measured(
            100, gear=(1e-36, 4.22e20), mass=(0.00237, 1e36), friction=(1e-36, 1e36), gravity=(1e-36, 4.22e7)
        ),
        "mjx": measured(
            100, "mjx", gear=(1e-36, 4.22e3), mass=(1e-36, 1e36), friction=(0.00237, 2.37e16), gravity=(1e-36, 1.78e5)
        ),
    },
    observation_size=27,  # the policy's input (a test builds the task and checks it)
    step_seconds=0.05,  # the env's dt (checked alike)
    anatomy=ANT_ANATOMY,
)

HOPPER = TaskSpec(
    name="hopper",
    help="Hopper, hop forward; descriptor: the foot's duty factor (QDax hopper_uni)",
    environment="hopper",
    factory="smol_dsl.tasks.feet:make",
    descriptor_low=(0.0,),
    descriptor_high=(1.0,),
    reward_offset=0.9,  # QDax's, for hopper_uni
    default_metric="max_fitness",
    presets={
        "paper": dict(batch_size=8192, episode_length=1000, hidden_layer_sizes=(64, 64)),
        "quick": dict(batch_size=128, episode_length=100, evaluations=65_536, hidden_layer_sizes=(64, 64)),
    },
    details={"feet": ("foot",)},
    factor_ranges={
        "spring": measured(
            1000, gear=(1e-36, 1.78e22), mass=(7.5e-9, 1e36), friction=(1e-36, 1e36), gravity=(1e-36, 1e36)
        ),
        "mjx": measured(
            1000, "mjx", gear=(1e-36, 1.78e8), mass=(1e-36, 1e36), friction=(1e-36, 1e36), gravity=(1e-36, 5.62e13)
        ),
    },
    observation_size=11,  # the policy's input (a test builds the task and checks it)
    step_seconds=0.008,  # the env's dt (checked alike)
    anatomy=Anatomy(
        actuators=("thigh_joint", "leg_joint", "foot_joint"),
        links=("torso", "thigh", "leg", "foot"),
        actuator_groups={"whole_leg": ("thigh_joint", "leg_joint", "foot_joint")},
        link_groups={"whole_leg": ("thigh", "leg", "foot")},  # "leg" is a link: the shin
    ),
)

ANT_UNI = TaskSpec(
    name="ant_uni",
    help="Ant, run forward; descriptor: each foot's duty factor (QDax ant_uni)",
    environment="ant",
    factory="smol_dsl.tasks.feet:make",
    descriptor_low=(0.0,) * 4,
    descriptor_high=(1.0,) * 4,
    reward_offset=3.24,  # QDax's, for ant_uni
    default_metric="max_fitness",
    presets={
        "paper": dict(batch_size=8192, episode_length=1000, hidden_layer_sizes=(64, 64)),
        "quick": dict(batch_size=64, episode_length=100, evaluations=25_600, hidden_layer_sizes=(64, 64)),
    },
    details={"feet": tuple(f"lower_leg_{i}" for i in "1234")},
    factor_ranges={
        "spring": measured(
            1000, gear=(1e-36, 4.22e20), mass=(0.00562, 1e36), friction=(1e-36, 1e36), gravity=(1e-36, 3.16e7)
        ),
        "mjx": measured(
            1000, "mjx", gear=(1e-36, 7.5e3), mass=(1e-36, 1e36), friction=(0.00237, 2.37e16), gravity=(1e-36, 1.78e5)
        ),
    },
    observation_size=27,  # the policy's input (a test builds the task and checks it)
    step_seconds=0.05,  # the env's dt (checked alike)
    anatomy=ANT_ANATOMY,
)
