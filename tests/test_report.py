"""`smol-dsl report`: the U-test table against tests computed by hand, layout, refusals."""

from __future__ import annotations

import csv
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from smol_dsl.cli import main
from smol_dsl.results.report import ReportError, load_runs, pvalue_table, write_report
from smol_dsl.rundir import ARCHIVE_FILE, METRICS_FILE, MetricsLog, write_archive
from smol_dsl.runner import preset_config
from smol_dsl.tasks import task_spec

SETTINGS = dict(evaluations=16 * 13, batch_size=16, num_phases=10, num_centroids=32, episode_length=20)


def write_run(
    directory: Path,
    library: dict,
    schedule: str,
    seed: int,
    final: dict[str, float],
    *,
    task: str = "walker2d",
    finished: bool = True,
    **overrides: object,
) -> Path:
    """A run directory in the runner's format (written by smol_dsl.rundir's writers) whose
    last row has the given final scores."""
    config = preset_config(task, "quick", seed=seed, **{**SETTINGS, **overrides})
    sched = library[schedule]
    directory.mkdir(parents=True)
    (directory / "config.json").write_text(config.to_json())
    (directory / "schedule.sched").write_text(sched.source)
    (directory / "certificate.json").write_text(json.dumps({"name": sched.name, "tail_start": float(sched.tail_start)}))
    last = config.generations if finished else config.generations // 2
    rng = np.random.default_rng(seed)
    rows = []
    for generation in range(last + 1):
        row = {
            "generation": generation,
            "phase": config.phase_of_generation(generation) if generation else 0,
            "alpha": 1.0,
            "event": "train" if generation else "init",
            "evaluations": (generation + 1) * config.batch_size,
            "reevaluations": 0,
            "coverage": rng.uniform(0, 50),
            "max_fitness": rng.uniform(0, 100),
            "qd_score": rng.uniform(0, 1000),
            "non_finite": 0,
        }
        if generation == last:
            row.update(final)
        rows.append(row)
    MetricsLog(directory / METRICS_FILE, rows)
    cells = config.num_centroids
    fitnesses = np.where(rng.uniform(size=cells) < 0.3, rng.uniform(0, 100, cells), -np.inf)
    write_archive(
        directory / ARCHIVE_FILE,
        {
            "genotypes/params/Dense_0/kernel": np.zeros((cells, 2, 2)),
            "fitnesses": fitnesses,
            "descriptors": rng.uniform(size=(cells, task_spec(task).descriptor_size)),
            "centroids": rng.uniform(size=(cells, task_spec(task).descriptor_size)),
        },
    )
    return directory


def exact_one_sided_p(x: list[float], y: list[float]) -> float:
    """P(U >= U_observed) for 'x greater than y', by enumerating every split of the pooled
    values (no ties): the exact Mann-Whitney U test, computed by hand."""

    def u_statistic(a: list[float], b: list[float]) -> float:
        return sum(1.0 if ai > bi else 0.5 if ai == bi else 0.0 for ai in a for bi in b)

    observed = u_statistic(x, y)
    pooled = x + y
    count = total = 0
    for chosen in itertools.combinations(range(len(pooled)), len(x)):
        a = [pooled[i] for i in chosen]
        b = [pooled[i] for i in range(len(pooled)) if i not in chosen]
        count += u_statistic(a, b) >= observed - 1e-12
        total += 1
    return count / total


def normal_one_sided_p(x: list[float], y: list[float]) -> float:
    """The large-sample U test with tie correction and continuity correction, by hand."""
    n1, n2 = len(x), len(y)
    u = sum(1.0 if a > b else 0.5 if a == b else 0.0 for a in x for b in y)
    _, counts = np.unique(x + y, return_counts=True)
    n = n1 + n2
    sigma = math.sqrt(n1 * n2 / 12 * ((n + 1) - np.sum(counts**3 - counts) / (n * (n - 1))))
    z = (u - n1 * n2 / 2 - 0.5) / sigma
    return 0.5 * math.erfc(z / math.sqrt(2))


SCORES = {
    "smol": [310.0, 295.5, 330.25, 301.0],
    "smol-reverse": [280.0, 305.0, 290.5, 260.0],
    "human": [300.5, 320.0, 299.0, 315.0],
    "vanilla": [250.0, 270.0, 262.0, 240.0],
}


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory, library) -> Path:
    root = tmp_path_factory.mktemp("synthetic")
    for schedule, scores in SCORES.items():
        for seed, score in enumerate(scores):
            write_run(root / f"walker2d-{schedule}-seed{seed}", library, schedule, seed, {"max_fitness": score})
    return root


def test_table_matches_u_tests_computed_by_hand(synthetic, library):
    groups = load_runs([synthetic])
    table = pvalue_table(groups)
    assert table.metric == "max_fitness"
    assert table.columns == ["SMOL", "SMOL-Reverse", "SMOL-Human"]
    assert table.rows == ["SMOL", "SMOL-Reverse", "SMOL-Human", "Vanilla MAP-Elites"]
    names = {library[key].name: key for key in SCORES}
    for row in table.rows:
        assert table.medians[row] == pytest.approx(float(np.median(SCORES[names[row]])))
        for column in table.columns:
            p = table.pvalues[row][column]
            if row == column:
                assert p is None
            else:
                expected = exact_one_sided_p(SCORES[names[column]], SCORES[names[row]])
                assert p == pytest.approx(expected, rel=1e-12), (row, column)
    # SMOL beats vanilla in every pairing: the smallest possible p with 4 runs each, 1/70
    assert table.pvalues["Vanilla MAP-Elites"]["SMOL"] == pytest.approx(1 / 70)


def test_large_samples_with_ties_use_the_normal_approximation(tmp_path, library):
    smol = [3.0, 5.0, 5.0, 7.0, 8.0, 9.0, 9.0, 10.0, 12.0]
    vanilla = [1.0, 2.0, 5.0, 5.0, 6.0, 7.0, 7.0, 8.0, 4.0]
    for seed, (a, b) in enumerate(zip(smol, vanilla, strict=True)):
        write_run(tmp_path / f"s{seed}", library, "smol", seed, {"coverage": a})
        write_run(tmp_path / f"v{seed}", library, "vanilla", seed, {"coverage": b})
    table = pvalue_table(load_runs([tmp_path]), "coverage")
    assert table.pvalues["Vanilla MAP-Elites"]["SMOL"] == pytest.approx(normal_one_sided_p(smol, vanilla), rel=1e-9)


def test_markdown_and_latex_layout(synthetic):
    table = pvalue_table(load_runs([synthetic]))
    markdown = table.markdown().splitlines()
    assert markdown[0] == (
        "| schedule | runs | median score | p: SMOL better | p: SMOL-Reverse better | p: SMOL-Human better |"
    )
    vanilla = next(line for line in markdown if line.startswith("| Vanilla"))
    assert "**1.429e-02**" in vanilla  # 1/70, significant
    smol = next(line for line in markdown if line.startswith("| SMOL |"))
    assert "| 305.5 | - |" in smol  # the diagonal
    human = next(line for line in markdown if line.startswith("| SMOL-Human |"))
    assert "**307.8**" in human  # the best median in bold
    latex = table.latex()
    assert "\\begin{tabular}{l|c|c|c|c|}" in latex
    assert "SMOL-Reverse & SMOL-Human \\\\" in latex
    assert "Vanilla MAP-Elites & 256.0 & \\textbf{1.429e-02}" in latex


def test_latex_escapes_names(tmp_path, library):
    for seed in range(2):
        write_run(tmp_path / f"e{seed}", library, "extinction-05", seed, {"max_fitness": 1.0 + seed})
        write_run(tmp_path / f"s{seed}", library, "smol", seed, {"max_fitness": 3.0 + seed})
    latex = pvalue_table(load_runs([tmp_path])).latex()
    assert "Extinction 5\\% &" in latex


def test_report_writes_table_scores_and_figures(synthetic, tmp_path):
    report = write_report([synthetic], tmp_path / "out")
    names = sorted(path.name for path in report.files)
    assert names == sorted(
        [
            "table.md",
            "pvalues.tex",
            "scores.csv",
            "main-results.png",
            "main-results.pdf",
            "archives.png",
            "archives.pdf",
        ]
    )
    assert all(path.stat().st_size > 0 for path in report.files)
    with open(tmp_path / "out" / "scores.csv") as file:
        rows = list(csv.DictReader(file))
    assert len(rows) == 16
    assert {float(r["max_fitness"]) for r in rows if r["schedule"] == "SMOL"} == set(SCORES["smol"])


def test_ablations_get_their_own_figure(tmp_path, library):
    for seed in range(2):
        for name in ("smol", "vanilla", "random", "extinction-10"):
            write_run(tmp_path / f"{name}-{seed}", library, name, seed, {"max_fitness": float(seed)})
    report = write_report([tmp_path], tmp_path / "out")
    names = {path.name for path in report.files}
    assert {"main-results.png", "ablation-results.png", "ablation-results.pdf"} <= names


def test_cli_report(synthetic, tmp_path, capsys):
    assert main(["report", str(synthetic), "-o", str(tmp_path / "r")]) == 0
    out = capsys.readouterr().out
    assert "walker2d, final max_fitness (16 runs)" in out
    assert "| Vanilla MAP-Elites | 4 | 256.0 |" in out
    assert (tmp_path / "r" / "pvalues.tex").is_file()


def test_refuses_no_runs(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ReportError, match="no run directories"):
        load_runs([tmp_path / "empty"])
    assert main(["report", str(tmp_path / "empty")]) == 2
    err = capsys.readouterr().err
    assert "smol-dsl report: error: no run directories" in err and "Traceback" not in err
    assert main(["report", str(tmp_path / "missing")]) == 2
    assert "no such directory" in capsys.readouterr().err


def test_refuses_runs_of_different_tasks(tmp_path, library, capsys):
    write_run(tmp_path / "a", library, "smol", 0, {"max_fitness": 1.0})
    write_run(tmp_path / "b", library, "smol", 1, {"max_fitness": 1.0}, task="halfcheetah")
    with pytest.raises(ReportError, match="different tasks"):
        load_runs([tmp_path])
    assert main(["report", str(tmp_path / "a"), str(tmp_path / "b"), "-o", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "different tasks (halfcheetah, walker2d)" in err and "Traceback" not in err


@pytest.mark.parametrize(
    ("second", "message"),
    [
        (dict(schedule="smol", seed=1, finished=False), "have not finished"),
        (dict(schedule="smol", seed=1, episode_length=30), "different settings"),
        (dict(schedule="smol", seed=0), "seed 0 is there twice"),
    ],
)
def test_refuses_runs_that_cannot_be_compared(tmp_path, library, second, message):
    write_run(tmp_path / "a", library, "smol", 0, {"max_fitness": 1.0})
    write_run(tmp_path / "b", library, final={"max_fitness": 2.0}, **second)
    with pytest.raises(ReportError, match=message):
        load_runs([tmp_path])


def test_a_directory_given_twice_counts_once(synthetic):
    groups = load_runs([synthetic, synthetic / "walker2d-smol-seed0"])
    assert sum(len(runs) for runs in groups.values()) == 16


def test_unknown_metric_is_a_usage_error(synthetic, capsys):
    assert main(["report", str(synthetic), "--metric", "speed"]) == 2
    assert "unknown metric 'speed'" in capsys.readouterr().err


def test_tied_best_medians_are_all_bold(tmp_path, library):
    for seed in range(2):
        write_run(tmp_path / f"s{seed}", library, "smol", seed, {"coverage": 6.25})
        write_run(tmp_path / f"v{seed}", library, "vanilla", seed, {"coverage": 6.25})
    table = pvalue_table(load_runs([tmp_path]), "coverage")
    assert table.best == {"SMOL", "Vanilla MAP-Elites"}
    assert table.markdown().count("**6.2**") == 2
    assert table.pvalues["Vanilla MAP-Elites"]["SMOL"] == pytest.approx(1.0)  # identical scores: no evidence
