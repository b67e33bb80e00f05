"""config.json: `RunConfig`, everything that determines a run besides its schedule's text;
`read_config`, which reads one back and checks every setting; and `setting_differences`,
which names the settings a saved config.json and a requested one differ in.

Imports neither JAX nor Brax nor sympy (`report` reads config.json with it)."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from smol_dsl.errors import Message, Setting, UserInputError
from smol_dsl.rundir.files import read_text
from smol_dsl.rundir.layout import CONFIG_FILE, RunDirectoryError, leave_out
from smol_dsl.seeds import check_seed
from smol_dsl.tasks import task_spec
from smol_dsl.tasks.physics import DEFAULT_PHYSICS, physics_problem

ISO_SIGMA = 0.005  # the paper's iso+line variation
LINE_SIGMA = 0.05


@dataclass(frozen=True)
class RunConfig:
    """Everything that determines a run, besides the schedule's text.

    `evaluations` is the training budget (offspring evaluated, the initial population
    included); re-evaluations at phase boundaries are counted separately.
    """

    task: str
    evaluations: int
    batch_size: int
    num_phases: int
    num_centroids: int
    episode_length: int
    hidden_layer_sizes: tuple[int, ...]
    seed: int = 0
    iso_sigma: float = ISO_SIGMA
    line_sigma: float = LINE_SIGMA
    num_init_cvt_samples: int = 50_000
    preset: str = "custom"
    physics: str = DEFAULT_PHYSICS  # what simulates the task: "spring" (the paper's) or "mjx" (`tasks.physics`)

    def __post_init__(self) -> None:
        # only seeds 0 .. 2**32 - 1 give distinct runs (smol_dsl.seeds); a SeedError otherwise
        object.__setattr__(self, "seed", check_seed(self.seed))

    @property
    def generations(self) -> int:
        """Generations after the initial population (which is generation 0)."""
        return self.evaluations // self.batch_size - 1

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2, sort_keys=True)


CONFIG_TYPES = {"str": str, "int": int, "float": float, "tuple[int, ...]": list}
"""The Python type each annotation of RunConfig's fields stands for in JSON."""
CONFIG_EXPECTED = {str: "a string", int: "a whole number", float: "a finite number", list: "a list of sizes"}
CONFIG_AT_LEAST_ONE = ("evaluations", "batch_size", "num_phases", "num_centroids", "episode_length")
"""The settings that count something the run needs at least one of."""


def read_config(path: Path) -> RunConfig:
    """A run's config.json, checked: every setting present, of its type, and usable."""
    fix = f"this is not a {CONFIG_FILE} that smol-dsl wrote; rerun the run, {leave_out(path.parent)}"
    data = _config_data(path, fix)
    _check_setting_names(path, data, fix)
    _check_setting_types(path, data, fix)
    _check_setting_values(path, data, fix)
    data["hidden_layer_sizes"] = tuple(data["hidden_layer_sizes"])
    try:
        config = RunConfig(**data)
    except (UserInputError, ValueError) as error:  # a seed outside 0 .. 2**32 - 1, say
        raise RunDirectoryError(
            f"{path}: {error}; rerun the run with settings the runner accepts, {leave_out(path.parent)}"
        ) from None
    _check_generations(path, config, fix)
    return config


def _config_data(path: Path, fix: str) -> dict[str, Any]:
    """config.json's JSON object."""
    text = read_text(path)
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as error:
        where = f":{error.lineno}" if isinstance(error, json.JSONDecodeError) else ""
        raise RunDirectoryError(f"{path}{where}: not valid JSON ({error}); {fix}") from None
    if not isinstance(data, dict):
        raise RunDirectoryError(f"{path}: holds {type(data).__name__}, not the run's settings; {fix}")
    return data


def _check_setting_names(path: Path, data: dict[str, Any], fix: str) -> None:
    """Every setting of RunConfig without a default is there, and no other."""
    fields = {field.name: field for field in dataclasses.fields(RunConfig)}
    missing = [name for name, field in fields.items() if name not in data and field.default is dataclasses.MISSING]
    if missing:
        raise RunDirectoryError(f"{path}: lacks the setting(s) {', '.join(missing)}; {fix}")
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise RunDirectoryError(
            f"{path}: unknown setting(s) {', '.join(unknown)} (from another smol-dsl version?); {fix}"
        )


def _check_setting_types(path: Path, data: dict[str, Any], fix: str) -> None:
    """Every setting is of its field's type (a bool is no number)."""
    types = {field.name: CONFIG_TYPES.get(str(field.type)) for field in dataclasses.fields(RunConfig)}
    for name, value in data.items():
        kind = types[name]
        if kind is not None and not _is_of_type(value, kind):
            raise RunDirectoryError(f"{path}: {name} is {json.dumps(value)[:40]}, not {CONFIG_EXPECTED[kind]}; {fix}")


def _is_of_type(value: Any, kind: type) -> bool:
    """Whether a JSON value is one of `kind` (CONFIG_TYPES' values): a finite float, a list of sizes of
    at least 1, or a str or int that is not a bool."""
    if kind is float:
        return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if kind is list:
        return isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in value)
    return isinstance(value, kind) and not isinstance(value, bool)


def _check_setting_values(path: Path, data: dict[str, Any], fix: str) -> None:
    """The task and the physics are known ones, and every count at least 1."""
    try:
        task_spec(data["task"])
    except ValueError as error:  # "unknown task 'x'; the tasks are ..."
        raise RunDirectoryError(f"{path}: {error}; {fix}") from None
    problem = physics_problem(data.get("physics", DEFAULT_PHYSICS))
    if problem is not None:
        raise RunDirectoryError(f"{path}: {problem}; {fix}")
    for name in CONFIG_AT_LEAST_ONE:
        if name in data and data[name] < 1:
            raise RunDirectoryError(f"{path}: {name} is {data[name]}, but must be at least 1; {fix}")


def _check_generations(path: Path, config: RunConfig, fix: str) -> None:
    """The budget makes a generation, and at least one per phase, as the runner requires."""
    if config.generations < 1:
        raise RunDirectoryError(
            f"{path}: {config.evaluations} evaluations in batches of {config.batch_size} make no generation; {fix}"
        )
    if config.generations < config.num_phases:
        raise RunDirectoryError(
            f"{path}: {config.num_phases} phases but only {config.generations} generations; the runner refuses "
            f"such settings, so smol-dsl did not write this file; {fix}"
        )


_MISSING = object()


def setting_differences(saved: dict[str, Any], requested: dict[str, Any], what: str) -> list[Message]:
    """One line per setting that differs between a saved config.json's object and a requested
    one, in RunConfig's order, naming the setting: "batch_size: the run was started with 64,
    not 128" (`what`: run or sweep)."""
    order = [field.name for field in dataclasses.fields(RunConfig)]
    names = order + sorted((set(saved) | set(requested)) - set(order))
    lines = []
    for name in names:
        old, new = saved.get(name, _MISSING), requested.get(name, _MISSING)
        if old != new:
            lines.append(Setting(name) + f": the {what} was started with {_shown(old)}, not {_shown(new)}")
    return lines


def _shown(value: Any) -> str:
    if value is _MISSING:
        return "no such setting"
    if isinstance(value, list):
        return "[" + ", ".join(str(v) for v in value) + "]"
    return str(value)
