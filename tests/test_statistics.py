"""The statistics the robustness tables add to the report's: Holm's adjustment for multiple
comparisons (`holm`, `adjusted_tables`) and the paired test (`paired_table`). Pure numbers:
nothing here trains or compiles."""

from __future__ import annotations

import budget
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import mannwhitneyu, wilcoxon

from smol_dsl.results.statistics import U_TEST, WILCOXON, adjusted_tables, holm, paired_table, score_table

pvalues = st.lists(st.floats(0, 1, allow_nan=False), min_size=0, max_size=30)


def reference_holm(raw: list[float]) -> list[float]:
    """Holm's adjusted p-values written from the definition, without a running maximum: the
    largest (m - r + 1) p over every p no larger, r a p's rank (its ties' first)."""
    m = len(raw)
    rank = [1 + sum(other < p for other in raw) for p in raw]
    return [min(1.0, max((m - rank[j] + 1) * raw[j] for j in range(m) if raw[j] <= p)) for p in raw]


@settings(max_examples=budget.examples(300))
@given(pvalues)
def test_holm_is_monotone_at_least_the_raw_p_at_most_1_and_its_definition(raw):
    adjusted = holm(raw)
    assert len(adjusted) == len(raw)
    for p, a in zip(raw, adjusted, strict=True):
        assert p <= a <= 1.0
    for i in range(len(raw)):
        for j in range(len(raw)):
            if raw[i] <= raw[j]:
                assert adjusted[i] <= adjusted[j]
    assert adjusted == pytest.approx(reference_holm(raw), abs=1e-12)


def test_holm_matches_r_s_p_adjust():
    # R: p.adjust(c(0.01, 0.04, 0.03, 0.005), "holm")
    assert holm([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])


def test_the_paired_test_pairs_by_seed_where_every_seed_is_present():
    smol = {0: 5.0, 1: 7.0, 2: 6.5, 3: 9.0, 4: 4.0}
    vanilla = {0: 4.0, 1: 6.0, 2: 6.0, 3: 7.0, 4: 4.5}
    random = {1: 1.0, 2: 2.0, 5: 3.0}  # other seeds: cannot be paired
    table = paired_table("walker2d", "score", {"SMOL": smol, "Vanilla MAP-Elites": vanilla, "Random": random})
    differences = [smol[seed] - vanilla[seed] for seed in sorted(smol)]
    assert table.test("Vanilla MAP-Elites", "SMOL") == WILCOXON
    assert table.pvalues["Vanilla MAP-Elites"]["SMOL"] == wilcoxon(differences, alternative="greater").pvalue
    assert table.test("Random", "SMOL") == U_TEST
    expected = mannwhitneyu(list(smol.values()), list(random.values()), alternative="greater").pvalue
    assert table.pvalues["Random"]["SMOL"] == pytest.approx(expected)
    same = paired_table("walker2d", "score", {"SMOL": smol, "Vanilla MAP-Elites": dict(smol)})
    assert same.pvalues["Vanilla MAP-Elites"]["SMOL"] == 1.0  # no difference anywhere: no evidence


def test_one_family_over_every_table_and_the_adjusted_p_is_the_one_in_bold():
    scores = {"SMOL": np.arange(10.0, 15.0), "Vanilla MAP-Elites": np.arange(5.0)}
    tables = {name: score_table("walker2d", name, scores) for name in ("a", "b", "c")}
    adjusted = adjusted_tables(tables)
    raw = tables["a"].pvalues["Vanilla MAP-Elites"]["SMOL"]
    assert adjusted["a"].adjusted["Vanilla MAP-Elites"]["SMOL"] == pytest.approx(3 * raw)
    assert f"**{raw:.3e} (Holm {3 * raw:.3e})**" in adjusted["a"].markdown()
    assert f"**{raw:.3e}**" in tables["a"].markdown()  # a table without adjustment: as the report's own
