"""Every entry point refuses the same bad input with the same message, before any work: one
table of cases, each tried through the command line (exit 2, its options named) and through
the Python API (`smol_dsl.runner`, `smol_dsl.qdax`: an exception, the settings named as
RunConfig's fields), where the entry point takes that input."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import pytest
from qdax.core.containers.mapelites_repertoire import MapElitesRepertoire
from small_runs import FLAGS, SETTINGS, cli, small_task

from smol_dsl import load
from smol_dsl import qdax as smol
from smol_dsl.runner import ConfigError, preset_config, run_experiment

SMALL = {**SETTINGS, "num_phases": 10}


def _flags(**changed: str) -> list[str]:
    """The small run's flags with some values changed (--evals 64 ...)."""
    flags = list(FLAGS)
    for option, value in changed.items():
        flags[flags.index(f"--{option.replace('_', '-')}") + 1] = value
    return flags


def _train(**settings: Any) -> Callable[[Path], Any]:
    """run_experiment of walker2d under smol.sched with the small settings changed."""

    def call(tmp: Path) -> Any:
        config = preset_config("walker2d", "quick", **{**SMALL, **settings})
        return run_experiment("walker2d", load("smol"), config, out_dir=tmp / "api")

    return call


def _score(body: list[float]) -> Callable[[Path], Any]:
    def call(tmp: Path) -> Any:
        task = small_task()
        score = smol.scoring_function(task, "smol")
        return score(task.init_policies(jax.random.key(0), 2), jax.random.key(0), jnp.asarray(body))

    return call


def _reevaluate(key: Any) -> Callable[[Path], Any]:
    def call(tmp: Path) -> Any:
        task = small_task()
        policies = task.init_policies(jax.random.key(0), 2)
        repertoire = MapElitesRepertoire.init_default(
            jax.tree.map(lambda leaf: leaf[0], policies), jnp.zeros((4, task.descriptor_size))
        )
        return smol.reevaluate(repertoire, smol.scoring_function(task, "smol"), jnp.ones(1), key)

    return call


@dataclass(frozen=True)
class Case:
    """A bad input: the command line that gives it (`{run}`: a finished small run) and the
    words its refusal says; the Python calls that give it, the exception and its words."""

    name: str
    argv: list[str] | None
    cli_words: str
    calls: tuple[Callable[[Path], Any], ...]
    error: type[Exception]
    api_words: str


CASES = [
    Case(
        "a budget of fewer generations than phases",
        ["run", "walker2d", "smol", *_flags(evals="64", batch_size="64", centroids="8", episode_length="10")],
        "use --evals 704 or more, fewer --phases, or a smaller --batch-size",
        (_train(evaluations=64, batch_size=64, num_centroids=8, episode_length=10),),
        ConfigError,
        "use evaluations 704 or more, fewer num_phases, or a smaller batch_size",
    ),
    Case(
        "phases that never reach the final body",
        ["run", "walker2d", "smol", *_flags(phases="3")],
        "so the run would not end on its final body; use --phases 10 or more",
        (_train(num_phases=3), lambda tmp: smol.phase_bodies("smol", 3)),
        ValueError,
        "so the run would not end on its final body; use num_phases 10 or more",
    ),
    Case(
        "an archive of one cell",
        ["run", "walker2d", "smol", *_flags(centroids="1")],
        "--centroids must be at least 2, not 1",
        (_train(num_centroids=1), lambda tmp: smol.run_start("walker2d", 0, batch_size=4, num_centroids=1)),
        ValueError,
        "num_centroids must be at least 2, not 1",
    ),
    Case(
        "an empty batch",
        ["run", "walker2d", "smol", *_flags(batch_size="0")],
        "--batch-size",
        (_train(batch_size=0), lambda tmp: smol.run_start("walker2d", 0, batch_size=0, num_centroids=8)),
        ValueError,
        "batch_size must be at least 1, not 0",
    ),
    Case(
        "fewer CVT samples than cells",
        None,
        "",
        (
            _train(num_init_cvt_samples=16),
            lambda tmp: smol.run_start("walker2d", 0, batch_size=4, num_centroids=32, num_init_cvt_samples=16),
        ),
        ValueError,
        "num_init_cvt_samples must be at least num_centroids (32), not 16",
    ),
    Case(
        "a gear beyond the task's physics",
        ["render", "{run}", "--body", "1e30", "-o", "{tmp}/g.gif"],
        "gear factor would be 1e+30, above what walker2d's physics takes",
        (_score([1e30]),),
        ValueError,
        "gear factor would be 1e+30, above what walker2d's physics takes",
    ),
    *(
        Case(
            f"a body of {value}",
            ["render", "{run}", "--body", value, "-o", "{tmp}/g.gif"],
            f"--body {value}: give `final`, `phase:K`, or 1 factor(s) above 0",
            (_score([float(value)]),),
            ValueError,
            "is not a factor: give a finite number above 0",
        )
        for value in ("0", "-1", "nan")
    ),
    Case(
        "a random schedule's bodies without its key",
        None,
        "",
        (lambda tmp: smol.phase_bodies("random", 10),),
        ValueError,
        "give key=schedule_key(seed)",
    ),
    Case(
        "a key that is not a JAX key",
        None,
        "",
        (_reevaluate(0), lambda tmp: smol.phase_bodies("random", 10, key=0)),
        TypeError,
        "key is one JAX random key, e.g. jax.random.key(0)",
    ),
    Case(
        "a task that is not the config's",
        None,
        "",
        (lambda tmp: run_experiment("hopper", load("smol"), preset_config("walker2d", **SMALL), out_dir=tmp / "api"),),
        ConfigError,
        "the task is hopper but the config's is walker2d",
    ),
]


@pytest.mark.parametrize("case", [case for case in CASES if case.argv is not None], ids=lambda case: case.name)
def test_the_command_line_refuses(case, small_run, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a run's default directory would be made here
    argv = [arg.format(run=small_run, tmp=tmp_path) for arg in case.argv]
    code, err = cli(argv, capsys)
    assert code == 2 and case.cli_words in err, err
    assert err.splitlines()[-1].startswith(f"smol-dsl {argv[0]}: error: ")  # argparse's usage may come first
    assert not (tmp_path / "runs").exists() and not (tmp_path / "g.gif").exists()


@pytest.mark.parametrize("case", CASES, ids=lambda case: case.name)
def test_the_python_api_refuses(case, tmp_path):
    for call in case.calls:
        with pytest.raises(case.error) as caught:
            call(tmp_path)
        assert case.api_words in str(caught.value)
        assert not (tmp_path / "api").exists()  # nothing written
