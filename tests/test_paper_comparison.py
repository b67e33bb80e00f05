"""The paper's table beside ours (results/paper.py): the shipped numbers, the verdicts, and
what the comparison says when the runs are not the paper's."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from smol_dsl.language.schedule import load
from smol_dsl.results.conditions import ABLATIONS, ORDER, PAPER_CONDITIONS, PAPER_TASKS
from smol_dsl.results.conditions import CURRICULA as COLUMNS
from smol_dsl.results.paper import (
    VERDICTS,
    compare_with_paper,
    pairwise_direction,
    paper_source,
    paper_table,
    verdict,
)
from smol_dsl.results.statistics import PValueTable
from smol_dsl.runner import preset_config


@pytest.mark.parametrize(
    ("task", "metric"), [("ant_omni", "coverage"), ("halfcheetah", "max_fitness"), ("walker2d", "max_fitness")]
)
def test_the_paper_s_tables_ship_with_the_package(task, metric):
    table = paper_table(task)
    assert table.metric == metric
    assert list(table.medians) == list(ORDER)  # the eight conditions, named as our schedules are
    for row, pvalues in table.pvalues.items():
        assert list(pvalues) == list(COLUMNS)
        for column, value in pvalues.items():
            assert (value is None) == (row == column)
            assert value is None or 0 < value < 1
    assert "pvalues.tex" in paper_source()
    assert paper_table("hopper") is None


def test_each_condition_is_named_as_its_bundled_schedule():
    """The report groups runs by their schedule's `name`; the conditions table must say the same."""
    for condition in PAPER_CONDITIONS:
        assert load(condition.schedule).name == condition.name
    assert len({condition.color for condition in PAPER_CONDITIONS}) == len(PAPER_CONDITIONS)
    assert COLUMNS == ("SMOL", "SMOL-Reverse", "SMOL-Human") and len(ABLATIONS) == 4
    assert sorted(paper_table(task) is not None for task in PAPER_TASKS) == [True] * 3


def test_known_cells_of_the_paper():
    walker, ant = paper_table("walker2d"), paper_table("ant_omni")
    assert walker.medians["SMOL"] == 4116 and walker.pvalues["SMOL-Reverse"]["SMOL"] == pytest.approx(6.165e-04)
    assert ant.medians["Vanilla MAP-Elites"] == 39 and ant.pvalues["Random"]["SMOL-Human"] == pytest.approx(7.010e-03)


@pytest.mark.parametrize(
    ("paper", "ours", "expected"),
    [
        (0.01, 0.02, "agrees"),
        (0.01, 0.2, "same direction"),
        (0.2, 0.3, "same direction"),
        (0.97, 0.7, "same direction"),
        (0.01, 0.9, "disagrees"),
        (0.8, 0.04, "disagrees"),
        (0.5, 0.5, "same direction"),
        (0.5, 0.01, "disagrees"),
    ],
)
def test_verdicts(paper, ours, expected):
    assert verdict(paper, ours) == expected


def test_tied_scores_point_nowhere_whatever_their_p_values():
    # two runs each, equal scores: scipy's one-sided p-value is 0.667 both ways
    assert pairwise_direction([0.6, 0.6], [0.6, 0.6]) == 0
    assert verdict(0.389, 0.667, 0) == "disagrees"  # the paper points one way, ours nowhere
    assert pairwise_direction([2.0, 3.0], [1.0, 2.0]) == 1 and pairwise_direction([1.0], [2.0]) == -1


probabilities = st.floats(0.0, 1.0, allow_nan=False)


@given(probabilities, probabilities)
def test_a_verdict_is_symmetric_and_agreement_needs_both_significant(paper, ours):
    assert verdict(paper, ours) == verdict(ours, paper) in VERDICTS
    if verdict(paper, ours) == "agrees":
        assert paper < 0.05 and ours < 0.05


def _table(task: str, metric: str, pvalue: float, runs: int = 5) -> PValueTable:
    names = list(ORDER)
    return PValueTable(
        task=task,
        metric=metric,
        rows=names,
        columns=list(COLUMNS),
        medians={name: 1.0 for name in names},
        runs={name: runs for name in names},
        pvalues={row: {column: None if row == column else pvalue for column in COLUMNS} for row in names},
    )


def _groups(preset: str, runs: int = 5, **overrides):
    """Runs whose scores rank the schedules in the paper's order (SMOL first)."""
    config = preset_config("ant_omni", preset, **overrides)
    return {
        name: [SimpleNamespace(config=config, final={"coverage": 100.0 - rank - seed / 10}) for seed in range(runs)]
        for rank, name in enumerate(ORDER)
    }


def test_runs_at_other_settings_compare_only_directions():
    comparison = compare_with_paper(_table("ant_omni", "coverage", 0.01), _groups("quick"))
    assert not comparison.paper_settings
    assert len(comparison.cells) == 8 * 3 - 3
    counts = comparison.counts()
    assert sum(counts.values()) == len(comparison.cells)
    summary = comparison.summary()
    assert "only directions and significance are comparable" in summary
    assert "evaluations 12800 (paper: 10000000)" in summary  # the quick budget, beside the paper's
    assert "5 seeds per condition" in summary
    text = comparison.markdown()
    assert "| SMOL-Reverse | SMOL | 0.0335 | 0.01 | agrees |" in text
    assert "| Vanilla MAP-Elites | 39 | (1) | 5 |" in text  # our median, marked as not comparable
    assert "\\begin{tabular}" in comparison.latex()


def test_runs_at_the_paper_s_settings_compare_medians():
    comparison = compare_with_paper(_table("ant_omni", "coverage", 0.01, runs=10), _groups("paper", runs=10))
    assert comparison.paper_settings and comparison.deviations == []
    assert "the medians are compared too." in comparison.summary()
    assert "| Vanilla MAP-Elites | 39 | 1 | 10 |" in comparison.markdown()


def test_another_metric_or_task_has_no_comparison():
    assert compare_with_paper(_table("ant_omni", "max_fitness", 0.01), _groups("quick")) is None
    assert compare_with_paper(_table("hopper", "max_fitness", 0.01), _groups("quick")) is None


def test_reproduce_plans_the_paper_s_eight_conditions(tmp_path, capsys):
    from small_runs import cli

    out = tmp_path / "reproduce"
    code, err = cli(
        ["reproduce", "walker2d", "--seeds", "3", "--evals", "2688", "--dry-run", "--no-measure", "--out", str(out)],
        capsys,
    )
    assert code == 0, err
    assert "smol-dsl reproduce: walker2d, 8 schedule(s) x 3 seed(s) = 24 runs" in err and "preset quick" in err
    assert not out.exists()
    code, err = cli(["reproduce", "hopper", "--dry-run"], capsys)
    assert code == 2 and "the paper ran walker2d, halfcheetah, ant_omni, not 'hopper'" in err


@pytest.mark.parametrize(("out", "robustness"), [(None, False), ("elsewhere", False), (None, True)])
def test_reproduce_reports_on_the_directory_its_sweep_wrote(tmp_path, capsys, monkeypatch, out, robustness):
    """The report reads the sweep's own output directory, --out's or the default."""
    from smol_dsl.cli import main
    from smol_dsl.cli import run as cli_run
    from smol_dsl.rescoring.replay import replay_elites
    from smol_dsl.results import gaits
    from smol_dsl.results import report as results_report
    from smol_dsl.results import robustness as results_robustness

    swept, reported, drawn, measured = [], [], [], []

    def start(self, plan, training, progress):
        swept.append(plan.out)
        final = {"evaluations": plan.config.evaluations, "reevaluations": 0}
        return [SimpleNamespace(seconds=1.0, final=final, config=plan.config)]

    def measure_and_write(paths, out_dir, perturbations=None, **options):
        assert not reported  # robustness.csv is written before the report reads it
        measured.append((paths, out_dir, options["force"]))

    def write_report(paths, out_dir, **options):
        reported.append((paths, out_dir))
        drawn.append((options["gaits"], options["replay"]))
        table = SimpleNamespace(task="walker2d", metric="max_fitness", markdown=lambda: "(the table)")
        return SimpleNamespace(table=table, comparison=None)

    monkeypatch.setattr(cli_run.Sweep, "start", start)
    monkeypatch.setattr(cli_run, "_draw_figures", lambda results: None)
    monkeypatch.setattr(results_report, "write_report", write_report)
    monkeypatch.setattr(results_robustness, "measure_and_write", measure_and_write)
    monkeypatch.setattr(gaits, "gl_backend", lambda: "egl")  # MuJoCo can render: the report has gaits
    monkeypatch.chdir(tmp_path)
    where = ([] if out is None else ["--out", out]) + (["--robustness"] if robustness else [])
    assert main(["reproduce", "walker2d", "--seeds", "1", "--evals", "2688", "--no-progress", *where]) == 0
    printed = capsys.readouterr().out
    expected = Path(out) if out is not None else Path("runs") / "walker2d-reproduce"
    assert swept == [expected] and reported == [([expected], expected / "report")]
    assert printed.splitlines()[0].startswith("done: 1 run of walker2d") and "(the table)" in printed
    assert drawn == [(1, replay_elites)]  # the best elite of each condition's median run, as `report` draws
    assert f"report: {expected / 'report'}" in printed
    assert measured == ([([expected], expected, True)] if robustness else [])
