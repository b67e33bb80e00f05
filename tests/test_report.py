"""`smol-dsl report`: the U-test table against tests computed by hand, layout, and refusals:
runs that cannot be compared, an output that would overwrite something, odd options, each
one message naming the file, exit status 2, no traceback, nothing written or overwritten;
names that tables and figures must escape; and reporting without loading JAX.

The run directories are synthetic (synthetic_runs.write_run, no training).
"""

from __future__ import annotations

import csv
import errno
import itertools
import json
import math
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from synthetic_runs import SEEDS, loaded_modules, many_schedules, refused, snapshot, write_run, write_runs

import smol_dsl
from smol_dsl.cli import main
from smol_dsl.results.report import REPORT_FILES, ROBUSTNESS_REPORT_FILES, write_report
from smol_dsl.results.runs import ReportError, load_runs
from smol_dsl.results.statistics import holm, pvalue_table
from smol_dsl.rundir import MetricsLog, read_metrics
from smol_dsl.rundir import files as rundir_files


@pytest.fixture(scope="module")
def pristine(tmp_path_factory, library) -> Path:
    """Six finished runs (synthetic_runs.write_runs), not to be changed: tests copy them."""
    return write_runs(tmp_path_factory.mktemp("pristine"), library)


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
        write_run(tmp_path / f"s{seed}", library, "smol", seed, {"coverage": a}, num_centroids=100)
        write_run(tmp_path / f"v{seed}", library, "vanilla", seed, {"coverage": b}, num_centroids=100)
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
            "index.html",
            "table.md",
            "pvalues.tex",
            "scores.csv",
            "main-results.png",
            "main-results.pdf",
            "archives.png",
            "archives.pdf",
            "paper-comparison.md",
            "paper-comparison.tex",
        ]
    )
    assert all(path.stat().st_size > 0 for path in report.files)
    comparison = (tmp_path / "out" / "paper-comparison.md").read_text()  # walker2d is one of the paper's
    assert "The runs lack Random, Extinction 5%, Extinction 10%, Extinction 50%" in comparison
    assert "| SMOL-Reverse | SMOL | 0.000616 |" in comparison  # the paper's 6.165e-04
    with open(tmp_path / "out" / "scores.csv") as file:
        rows = list(csv.DictReader(file))
    assert len(rows) == 16
    assert {float(r["max_fitness"]) for r in rows if r["schedule"] == "SMOL"} == set(SCORES["smol"])


def test_the_report_s_table_gives_holm_beside_each_p_and_the_paper_comparison_the_raw_p(synthetic, tmp_path):
    raw = pvalue_table(load_runs([synthetic]))
    cells = raw.cells()
    adjusted = dict(zip(cells, holm([raw.pvalues[row][column] for row, column in cells]), strict=True))
    write_report([synthetic], tmp_path / "out")
    table = (tmp_path / "out" / "table.md").read_text()
    assert len(cells) == 9  # 4 schedules x 3 curricula, less the diagonal
    assert f"Holm-adjusted value over the table's {len(cells)} tests" in table
    vanilla = next(line for line in table.splitlines() if line.startswith("| Vanilla"))
    holm_vanilla = adjusted["Vanilla MAP-Elites", "SMOL"]
    assert f"1.429e-02 (Holm {holm_vanilla:.3e})" in vanilla and holm_vanilla > 0.05  # 1/70, not after adjusting
    assert "**1.429e-02" not in vanilla  # bold only where the adjusted p is below 0.05
    # 4 runs each: a raw p can reach 1/70, but 9 x 1/70 cannot, and the table says so
    assert "no adjusted p-value can be below 0.05 (the smallest possible is 0.129)" in table
    for row, column in cells:
        assert f"{raw.pvalues[row][column]:.3e} (Holm {adjusted[row, column]:.3e})" in table
    assert "(Holm" in (tmp_path / "out" / "pvalues.tex").read_text()
    assert "(Holm" in (tmp_path / "out" / "index.html").read_text()
    assert "Holm" not in (tmp_path / "out" / "paper-comparison.md").read_text()  # the paper's p are raw, as ours there


def test_runs_that_count_their_reevaluations_get_a_reevaluation_figure(tmp_path, library):
    """Runs whose reevaluate rows count the elites kept (as the runner writes them) get
    reevaluation.png, shown on the page; runs written before the counts existed (as the
    `synthetic` fixture's) get every other file."""
    for seed in range(2):
        for name in ("smol", "vanilla"):
            write_run(tmp_path / f"{name}-{seed}", library, name, seed, {"max_fitness": float(seed)}, reevaluate=True)
    names = {path.name for path in write_report([tmp_path], tmp_path / "out").files}
    assert {"reevaluation.png", "reevaluation.pdf", "main-results.png"} <= names
    assert 'src="reevaluation.png"' in (tmp_path / "out" / "index.html").read_text()


def test_ablations_get_their_own_figure(tmp_path, library):
    for seed in range(2):
        for name in ("smol", "vanilla", "random", "extinction-10"):
            write_run(tmp_path / f"{name}-{seed}", library, name, seed, {"max_fitness": float(seed)})
    report = write_report([tmp_path], tmp_path / "out")
    names = {path.name for path in report.files}
    assert {"main-results.png", "ablation-results.png", "ablation-results.pdf"} <= names


def test_cli_report(synthetic, tmp_path, capsys):
    assert main(["report", str(synthetic), "-o", str(tmp_path / "r"), "--no-gaits"]) == 0
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


def test_refuses_two_schedules_with_one_name(tmp_path, library):
    schedules = {}
    for key, factor in (("a", "1.2"), ("b", "1.3")):
        path = tmp_path / f"{key}.sched"
        path.write_text(f'name "Same"\n0% .. 90%: constant {factor}\n90% .. 100%: tail\n')
        schedules[key] = smol_dsl.load(path)
    first = write_run(tmp_path / "runs" / "a", schedules, "a", 0, {"max_fitness": 1.0})
    second = write_run(tmp_path / "runs" / "b", schedules, "b", 1, {"max_fitness": 2.0})
    with pytest.raises(ReportError) as caught:
        load_runs([tmp_path / "runs"])
    assert str(caught.value) == (
        f"two different schedules are both named 'Same' ({first} and {second}); give them different `name`s"
    )


def test_refuses_runs_of_the_same_settings_that_log_different_steps(tmp_path, library):
    write_run(tmp_path / "a", library, "smol", 0, {"max_fitness": 1.0})
    edited = write_run(tmp_path / "b", library, "vanilla", 0, {"max_fitness": 1.0})
    rows = read_metrics(edited / "metrics.csv")
    boundary = next(i for i in range(len(rows) - 1) if rows[i + 1]["phase"] > rows[i]["phase"])
    rows.insert(boundary + 1, {**rows[boundary], "event": "reevaluate", "phase": rows[boundary + 1]["phase"]})
    MetricsLog(edited / "metrics.csv", rows)  # a valid file, with a re-evaluation the other run lacks
    with pytest.raises(ReportError) as caught:
        load_runs([tmp_path])
    assert str(caught.value).startswith(
        f"{edited / 'metrics.csv'} (14 rows) and {tmp_path / 'a' / 'metrics.csv'} (13 rows) log different "
        "generations and phases although their runs have the same settings; one of them was cut or edited"
    )


def test_refuses_schedules_that_end_on_different_bodies(tmp_path, library):
    plain = write_run(tmp_path / "a", library, "smol", 0, {"max_fitness": 1.0})
    damaged = write_run(tmp_path / "b", library, "leg-damage", 0, {"max_fitness": 1.0})
    with pytest.raises(ReportError) as caught:
        load_runs([tmp_path])
    assert str(caught.value).startswith(
        f"Leg damage and SMOL end on different bodies: thigh_left_joint's gear factor ends at 0.5 in Leg damage "
        f"({damaged}) and at 1 in SMOL ({plain}); final scores are only comparable on the same final body"
    )
    write_run(tmp_path / "c", library, "growth", 0, {"max_fitness": 1.0})  # ends on the standard body
    assert list(load_runs([tmp_path / "a", tmp_path / "c"])) == ["SMOL", "Growth"]


def test_bodies_are_compared_part_by_part_however_the_files_spell_them(tmp_path, library):
    """leg-damage's `gear[left_leg]` and a copy naming the left leg's three joints end on one body."""
    joints = library["leg-damage"].source.replace(
        "gear[left_leg]", "gear[thigh_left_joint, leg_left_joint, foot_left_joint]"
    )
    spelled = {"joints": smol_dsl.parse(joints.replace('name "Leg damage"', 'name "Leg damage by joints"'))}
    write_run(tmp_path / "a", library, "leg-damage", 0, {"max_fitness": 1.0})
    write_run(tmp_path / "b", spelled, "joints", 0, {"max_fitness": 2.0})
    assert sorted(load_runs([tmp_path])) == ["Leg damage", "Leg damage by joints"]


# ---------------------------------------------------------------- derived, not believed


def edit_json(path: Path, **changes: object) -> None:
    data = json.loads(path.read_text())
    data.update(changes)
    path.write_text(json.dumps(data))


def test_a_config_naming_another_task_is_refused_by_the_archive_s_shapes(tmp_path, library):
    run = write_run(tmp_path / "a", library, "vanilla", 0, {"max_fitness": 1.0})
    edit_json(run / "config.json", task="ant_omni")  # 2 descriptors too, but 27 observations and 8 actions
    with pytest.raises(ReportError) as caught:
        load_runs([run])
    assert str(caught.value).startswith(
        f"{run / 'archive.npz'}: genotypes/params/Dense_0/kernel has shape (32, 17, 64), but ant_omni's network "
        "in config.json gives (32, 27, 64)"
    )


def test_a_config_naming_a_task_of_the_same_network_is_refused_by_the_qd_score(tmp_path, library):
    """halfcheetah's policies have walker2d's shapes; its QD score's offset per cell does not."""
    run = write_run(tmp_path / "a", library, "vanilla", 0, {"max_fitness": 1.0})
    edit_json(run / "config.json", task="halfcheetah")
    with pytest.raises(ReportError) as caught:
        load_runs([run])
    assert re.match(
        rf"{re.escape(str(run / 'metrics.csv'))}: its last row's qd_score \(-?[\d.]+\) is not what the elites of "
        r"archive.npz score under config.json's task halfcheetah \(-?[\d.]+\); the files are from different runs",
        str(caught.value),
    ), caught.value


@pytest.mark.parametrize("score", ["coverage", "max_fitness", "qd_score"])
def test_final_scores_that_the_archive_does_not_give_are_refused(tmp_path, library, score):
    run = write_run(tmp_path / "a", library, "vanilla", 0, {"max_fitness": 1.0})
    rows = read_metrics(run / "metrics.csv")
    rows[-1][score] += 1.0
    MetricsLog(run / "metrics.csv", rows)
    with pytest.raises(ReportError, match=f"its last row's {score} "):
        load_runs([run])


def test_a_config_whose_task_lacks_the_schedule_s_body_is_refused(tmp_path, library):
    run = write_run(tmp_path / "a", library, "leg-damage", 0, {"max_fitness": 1.0})
    edit_json(run / "config.json", task="hopper")
    with pytest.raises(ReportError, match=r"schedule.sched:8:14: error: task hopper has no actuators named `left_leg`"):
        load_runs([run])


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        (
            "final_body",
            {},
            "its 'final_body' (none (every factor 1)) is not what schedule.sched proves (gear[left_leg] 0.5)",
        ),
        ("channels", {"gear": None}, "its 'channels' (gear) is not what schedule.sched proves (gear[left_leg])"),
        ("tail_start", 0.5, "its 'tail_start' (0.5) is not what schedule.sched proves (0.9)"),
    ],
)
def test_a_certificate_that_disagrees_with_its_schedule_is_refused(tmp_path, library, field, value, message):
    run = write_run(tmp_path / "a", library, "leg-damage", 0, {"max_fitness": 1.0})
    edit_json(run / "certificate.json", **{field: value})
    with pytest.raises(ReportError) as caught:
        load_runs([run])
    assert str(caught.value).startswith(f"{run / 'certificate.json'}: {message}"), caught.value


def edit_columns(path: Path, edit) -> None:
    with open(path, newline="") as file:
        rows = list(csv.reader(file))
    with open(path, "w", newline="") as file:
        csv.writer(file).writerows(edit(rows))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda rows: [row[:3] + row[4:] for row in rows], "the header lacks the column(s) mass"),
        (lambda rows: [[*rows[0][:3], "mass[torso]", *rows[0][4:]], *rows[1:]], "the header lacks the column(s) mass"),
        (lambda rows: [[*row, row[3]] for row in rows], "names a column twice"),
        (lambda rows: [rows[0] + ["friction"], *([*row, "1.0"] for row in rows[1:])], "does not schedule"),
        (lambda rows: [rows[0] + ["mass[ torso]"], *([*row, "1.0"] for row in rows[1:])], "does not schedule"),
    ],
    ids=["deleted", "renamed", "doubled", "another channel", "another spelling"],
)
def test_metrics_columns_are_the_schedule_s_channels(tmp_path, library, edit, message):
    run = write_run(tmp_path / "a", library, "growth", 0, {"max_fitness": 1.0})  # columns alpha, mass
    assert (run / "metrics.csv").read_text().startswith("generation,phase,alpha,mass,")
    edit_columns(run / "metrics.csv", edit)
    with pytest.raises(ReportError) as caught:
        load_runs([run])
    assert f"{run / 'metrics.csv'}:1: the header" in str(caught.value) and message in str(caught.value)


def test_a_metrics_file_with_a_byte_order_mark_is_read(tmp_path, library):
    run = write_run(tmp_path / "a", library, "vanilla", 0, {"max_fitness": 1.0})
    path = run / "metrics.csv"
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())  # as a spreadsheet saves UTF-8
    (runs,) = load_runs([run]).values()
    assert runs[0].final["max_fitness"] == 1.0


def test_many_unusable_run_directories_are_listed_up_to_five(tmp_path, library):
    for seed in range(7):
        run = write_run(tmp_path / f"run{seed}", library, "smol", seed, {"max_fitness": 1.0})
        (run / "schedule.sched").unlink()
    with pytest.raises(ReportError) as caught:
        load_runs([tmp_path])
    lines = str(caught.value).splitlines()
    assert lines[0] == "7 of the 7 run directories cannot be used:"
    for seed in range(5):
        assert lines[1 + seed].startswith(f"  {tmp_path / f'run{seed}' / 'schedule.sched'}: missing"), lines
    assert lines[6:] == ["  and 2 more"]


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


# ---------------------------------------------------------------------------- seeds
def test_the_same_schedule_and_seed_twice_is_refused(pristine, tmp_path, capsys):
    again = tmp_path / "again"
    shutil.copytree(pristine / "walker2d-smol-seed1", again / "copy-of-seed1")
    err = refused(
        ["report", str(pristine), str(again), "-o", str(tmp_path / "out")],
        capsys,
        pristine / "walker2d-smol-seed1",
        again / "copy-of-seed1",
    )
    assert "seed 1 is there twice" in err


def test_seeds_that_jax_takes_as_equal_are_refused(pristine, tmp_path, capsys):
    alias = Path(shutil.copytree(pristine / "walker2d-smol-seed1", tmp_path / "alias" / "seed-4294967297"))
    config = json.loads((alias / "config.json").read_text())
    (alias / "config.json").write_text(json.dumps({**config, "seed": 1 + 2**32}))  # the same stream as seed 1
    err = refused(["report", str(pristine), str(tmp_path / "alias"), "-o", str(tmp_path / "out")], capsys, alias)
    assert "4294967297" in err
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------------------- the output
def test_an_earlier_report_is_kept_unless_forced(pristine, tmp_path, capsys, library):
    out = tmp_path / "report"
    with_ablation = Path(shutil.copytree(pristine, tmp_path / "runs"))
    for seed in SEEDS:
        write_run(with_ablation / f"random-{seed}", library, "random", seed, {"max_fitness": 1.0})
    assert main(["report", str(with_ablation), "-o", str(out), "--no-gaits"]) == 0
    capsys.readouterr()
    before = snapshot(out)
    assert "ablation-results.png" in before

    err = refused(["report", str(pristine), "-o", str(out)], capsys, out, "--force", "-o", "table.md")
    assert snapshot(out) == before  # untouched
    with pytest.raises(ReportError, match="already holds a report"):
        write_report([pristine], out)

    assert main(["report", str(pristine), "-o", str(out), "--force", "--no-gaits"]) == 0
    after = snapshot(out)
    assert after["table.md"] != before["table.md"]
    assert "ablation-results.png" not in after  # the earlier report's figure that this one does not draw
    assert not [name for name in after if name.endswith(".tmp")]
    del err


def test_output_that_is_a_file_is_refused(pristine, tmp_path, capsys):
    target = tmp_path / "results.md"
    target.write_text("my notes")
    refused(["report", str(pristine), "-o", str(target)], capsys, target, "not a directory")
    assert target.read_text() == "my notes"
    refused(["report", str(pristine), "-o", str(target / "report")], capsys, target, "is a file")
    assert target.read_text() == "my notes"


def test_output_that_is_a_run_directory_is_refused(pristine, tmp_path, capsys):
    run = next(path.parent for path in sorted(pristine.rglob("metrics.csv")))
    before = sorted(path.name for path in run.iterdir())
    refused(["report", str(pristine), "-o", str(run)], capsys, run, "is a run directory")
    assert sorted(path.name for path in run.iterdir()) == before


def test_output_in_a_new_directory_is_made(pristine, tmp_path, capsys):
    out = tmp_path / "not" / "yet" / "there"
    assert main(["report", str(pristine), "-o", str(out), "--no-gaits"]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [
            "index.html",
            "table.md",
            "pvalues.tex",
            "scores.csv",
            "main-results.png",
            "main-results.pdf",
            "archives.png",
            "archives.pdf",
            "paper-comparison.md",
            "paper-comparison.tex",
        ]
    )
    assert "wrote" in capsys.readouterr().out


def test_a_report_file_name_taken_by_a_directory_is_refused(pristine, tmp_path, capsys):
    out = tmp_path / "out"
    (out / "scores.csv").mkdir(parents=True)
    refused(["report", str(pristine), "-o", str(out), "--force"], capsys, out / "scores.csv", "is a directory")
    assert [p.name for p in out.iterdir()] == ["scores.csv"]


def test_a_full_disk_leaves_the_earlier_report_whole(pristine, tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    assert main(["report", str(pristine), "-o", str(out), "--no-gaits"]) == 0
    capsys.readouterr()
    before = snapshot(out)
    written = []

    def full_disk(path: Path, data: bytes) -> None:
        if len(written) == 3:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        written.append(path)
        path.write_bytes(data)

    monkeypatch.setattr(rundir_files, "_write_bytes", full_disk)
    refused(["report", str(pristine), "-o", str(out), "--force", "--no-gaits"], capsys, "No space left on device", out)
    assert snapshot(out) == before  # nothing renamed into place, every temporary file removed
    assert len(written) == 3


def test_no_runs_missing_and_odd_directories(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    refused(["report", str(tmp_path / "empty")], capsys, tmp_path / "empty", "no run directories")
    assert not (tmp_path / "empty" / "report").exists()
    refused(["report", str(tmp_path / "missing")], capsys, tmp_path / "missing", "no such directory")
    (tmp_path / "file.txt").write_text("x")
    refused(["report", str(tmp_path / "file.txt")], capsys, tmp_path / "file.txt", "not a directory")


def test_report_option_mistakes(pristine, tmp_path, capsys):
    refused(["report", str(pristine), str(pristine), "--metric", "coverage"], capsys, "-o OUT")
    refused(["report", str(pristine), "-o", str(tmp_path / "o"), "--metric", "speed"], capsys, "unknown metric")
    refused(["report", str(pristine), str(pristine), "-o", ""], capsys, "-o: empty path")
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------------------- many schedules, odd names
@pytest.mark.slow  # a report of many schedules
def test_report_of_many_schedules_without_warnings(tmp_path, capsys):
    schedules = {f"s{k}": smol_dsl.load(p) for k, p in enumerate(many_schedules(tmp_path, 12), start=1)}
    for name in schedules:
        write_run(tmp_path / "runs" / name, schedules, name, 0, {"max_fitness": float(len(name))}, reevaluate=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["report", str(tmp_path / "runs"), "-o", str(tmp_path / "out"), "--no-gaits"]) == 0
    err = capsys.readouterr().err
    assert all(line.startswith("note: ") for line in err.splitlines()), err
    without = {"ablation-results.png", "ablation-results.pdf", *ROBUSTNESS_REPORT_FILES}  # no ablations, robustness
    assert set(REPORT_FILES) - without == {p.name for p in (tmp_path / "out").iterdir()}


def test_names_with_table_and_latex_characters(tmp_path, capsys):
    schedules = {}
    for key, name in (("pipe", "a|b"), ("tex", "x\\y^2~_{z}")):
        path = tmp_path / f"{key}.sched"
        path.write_text(f'name "{name}"\n0% .. 90%: constant 1.2\n90% .. 100%: tail\n')
        schedules[key] = smol_dsl.load(path)
    for key in schedules:
        for seed in (0, 1):
            write_run(tmp_path / "runs" / f"{key}-{seed}", schedules, key, seed, {"max_fitness": float(seed)})
    assert main(["report", str(tmp_path / "runs"), "-o", str(tmp_path / "out"), "--no-gaits"]) == 0
    markdown = (tmp_path / "out" / "table.md").read_text().splitlines()
    rows = [line for line in markdown if line.startswith("| ") and "---" not in line]
    assert all(line.count(" | ") == rows[0].count(" | ") for line in rows)  # one cell per column
    assert any(line.startswith("| a\\|b |") for line in rows)
    latex = (tmp_path / "out" / "pvalues.tex").read_text()
    assert "x\\textbackslash{}y\\textasciicircum{}2\\textasciitilde{}\\_\\{z\\}" in latex


# ---------------------------------------------------------------------------- import weight
HEAVY = ("jax", "brax", "qdax", "flax")
"""What reporting on runs must not load: training's libraries."""


def test_the_report_module_imports_no_jax():
    assert loaded_modules("import smol_dsl.results.report", HEAVY) == []
    figures = "smol_dsl.results.figures, smol_dsl.results.run_figures, smol_dsl.results.schedule_figures"
    assert loaded_modules(f"import smol_dsl.results.report, smol_dsl.rundir, {figures}", HEAVY) == []


def test_cli_report_without_gaits_imports_no_jax(tmp_path, library):
    for schedule in ("smol", "vanilla"):
        for seed in (0, 1):
            write_run(tmp_path / "runs" / f"{schedule}-{seed}", library, schedule, seed, {"max_fitness": seed})
    code = (
        "from smol_dsl.cli import main\n"
        f"assert main(['report', {str(tmp_path / 'runs')!r}, '-o', {str(tmp_path / 'out')!r}, '--no-gaits']) == 0"
    )
    assert loaded_modules(code, HEAVY) == []
    assert (tmp_path / "out" / "table.md").is_file()
