"""The bundled tasks' specs: QDax's locomotion tasks, sized as in the paper.

Presets: "paper" is the paper's table of hyperparameters per task (its 1e7 evaluations,
100 phases and 1024 cells are common to all, in smol_dsl.runner.config); "quick" is sized
so that `smol-dsl run walker2d human.sched` takes about 4 minutes on 2 CPU cores (raw
rollouts run at ~210 walker2d evaluations/s at 100 steps, ~50 halfcheetah, ~90 ant).
"""

from __future__ import annotations

from smol_dsl.language.channels import BodyPlan
from smol_dsl.tasks.registry import TaskSpec

DUTY_FACTORS = ((0.0, 0.0), (1.0, 1.0))  # two feet, each in contact a proportion of the steps

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
    body=BodyPlan(
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
)
