"""Verdicts over seeds (docs/specification.md section 10), on hand-made scores."""

import pytest

from flock_torchrl.report.claims import CLAIMS
from flock_torchrl.report.seeds import (claim_verdict, claims_table, compare, comparisons_of, iqm,
                                        probability_of_improvement, summarise, verdict)


def test_probability_of_improvement_counts_pairs_and_half_ties():
    # x = [1, 2, 3], y = [2, 2]: pairs above: (3,2),(3,2) = 2; ties: (2,2),(2,2) = 2; of 6 pairs:
    # (2 + 0.5 * 2) / 6 = 0.5
    assert probability_of_improvement([1, 2, 3], [2, 2]) == pytest.approx(0.5)
    # every seed of x above every seed of y: 1; the reverse: 0
    assert probability_of_improvement([5, 6], [1, 2, 3]) == 1.0
    assert probability_of_improvement([1, 2, 3], [5, 6]) == 0.0


def test_iqm_trims_a_quarter_from_each_end():
    # sorted: -100, 1, 2, 3, 4, 5, 6, 100; drop the 2 lowest and 2 highest: mean of [2, 3, 4, 5] = 3.5
    assert iqm([100, 1, 2, 3, 4, 5, 6, -100]) == pytest.approx(3.5)


def test_verdict_rule():
    assert verdict(0.6, 0.9, 10) == "holds"
    assert verdict(0.1, 0.4, 10) == "reversed"
    assert verdict(0.4, 0.7, 10) == "not distinguishable"
    assert verdict(0.9, 1.0, 2) == "too few seeds"


def test_clearly_separated_seeds_hold_and_overlapping_ones_do_not():
    apart = compare("A", "B", {"A": [0.9, 0.92, 0.95, 0.91, 0.93], "B": [0.6, 0.62, 0.65, 0.61, 0.63]})
    assert (apart.probability, apart.verdict) == (1.0, "holds")
    assert apart.low == 1.0   # every resample keeps every A above every B
    mixed = compare("A", "B", {"A": [0.6, 0.9, 0.7, 0.8, 0.65], "B": [0.62, 0.88, 0.72, 0.78, 0.66]})
    assert mixed.verdict == "not distinguishable"
    assert mixed.low < 0.5 < mixed.high
    reversed_ = compare("B", "A", {"A": [0.9, 0.92, 0.95], "B": [0.6, 0.62, 0.65]})
    assert reversed_.verdict == "reversed"


def test_summary_interval_contains_the_mean_and_is_reproducible():
    scores = [0.8, 0.85, 0.9, 0.95, 0.7, 0.75]
    a, b = summarise(scores), summarise(scores)
    assert a == b
    assert a.mean == pytest.approx(0.825)  # (0.8 + 0.85 + 0.9 + 0.95 + 0.7 + 0.75) / 6
    assert a.mean_low <= a.mean <= a.mean_high and a.mean_low < a.mean_high
    assert (a.minimum, a.maximum, a.n) == (0.7, 0.95, 6)


def test_claims_read_in_their_own_direction():
    critic = next(c for c in CLAIMS if "critic" in c.text)
    scores = {"Policy1": [0.5] * 3, "Policy1-G": [0.9] * 3, "Policy2": [0.9] * 3, "Policy2-G": [0.5] * 3}
    found = comparisons_of(critic, scores)
    assert [(c.better, c.worse, c.verdict) for c in found] == [("Policy1-G", "Policy1", "holds"),
                                                               ("Policy2-G", "Policy2", "reversed")]
    assert claim_verdict(found) == "1 holds, 1 reversed"
    compact = next(c for c in CLAIMS if "field of view" in c.text)
    d_c = {"Policy1": [1.0, 1.1, 1.2], "Policy2": [3.0, 3.1, 3.2]}
    assert [(c.better, c.worse, c.verdict) for c in comparisons_of(compact, d_c)] == [("Policy2", "Policy1", "holds")]


def test_claims_table_from_a_seeds_csv(tmp_path):
    path = tmp_path / "t_seeds.csv"
    rows = ["policy,extra,success_rate,d_min_uav,d_c"]
    for seed in range(3):
        rows += [f"Policy5-G,,{0.99 - seed / 100},1.7,3.0", f"Policy3-G,,{0.90 + seed / 100},1.6,3.1"]
    path.write_text("\n".join(rows) + "\n")
    table = claims_table(path)
    assert "| Policy3-G above Policy5-G | 3 / 3 | 0.00 [0.00, 0.00] | reversed |" in table
