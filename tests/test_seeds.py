"""Verdicts over seeds (docs/specification.md section 10), on hand-made scores."""

import re

import pytest

from flock_torchrl.report.claims import CLAIMS
import numpy as np

from flock_torchrl.report.seeds import (SMALLEST_DIFFERENCE, claim_verdict, claims_overview, claims_table, compare,
                                        comparisons_of, iqm, performance_profile, plot_profiles,
                                        probability_of_improvement, score_distribution, smallest_difference,
                                        summarise, summary_table, verdict, write_claims)
from helpers import ROOT


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
    # P's interval and the difference's interval, smallest difference 0.01
    assert verdict(0.6, 0.9, 10, 0.02, 0.05, 0.01) == "holds"
    assert verdict(0.1, 0.4, 10, -0.05, -0.02, 0.01) == "reversed"
    assert verdict(0.4, 0.7, 10, 0.02, 0.05, 0.01) == "not distinguishable"   # P's interval holds 0.5
    assert verdict(0.6, 0.9, 10, 0.005, 0.05, 0.01) == "not distinguishable"  # the difference may be too small
    assert verdict(0.1, 0.4, 10, -0.05, -0.009, 0.01) == "not distinguishable"
    assert verdict(0.6, 0.9, 10, 0.01, 0.05, 0.01) == "not distinguishable"   # clearing means strictly beyond
    assert verdict(0.9, 1.0, 2, 0.5, 0.6, 0.01) == "too few seeds"


def test_smallest_differences_are_the_specifications():
    """docs/specification.md section 10 states them; an unknown metric is refused, naming it."""
    assert SMALLEST_DIFFERENCE == {"success_rate": 0.01, "safe_success_rate": 0.01, "d_min_uav": 0.1, "d_c": 0.1,
                                   "t_goal": 1.0}
    spec = (ROOT / "docs" / "specification.md").read_text()
    section = spec.split("## 10.", 1)[1]
    assert "success rate and safe success rate 0.01 (one point), `d_min_uav` 0.1 m and `d_c`\n  0.1 m" in section
    assert "`t_goal` 1 s" in section
    with pytest.raises(ValueError, match="'speed'"):
        smallest_difference("speed")


def test_a_sure_but_tiny_difference_is_not_distinguishable():
    """By hand: four seeds at 0.999 against four at 0.998 (no spread, so every resample is the
    data): P(X > Y) = 1 with interval [1, 1], clearing 0.5, but the difference of means is
    0.001 [0.001, 0.001], below one point: not distinguishable. The reverse likewise."""
    scores = {"X": [0.999] * 4, "Y": [0.998] * 4}
    c = compare("X", "Y", scores, "success_rate")
    assert (c.probability, c.low, c.high) == (1.0, 1.0, 1.0)
    assert c.difference == pytest.approx(0.001) and (c.difference_low, c.difference_high) == pytest.approx((0.001, 0.001))
    assert c.verdict == "not distinguishable"
    assert compare("Y", "X", scores, "success_rate").verdict == "not distinguishable"
    # the same seeds ten points apart: P = 1 and the difference 0.1 [0.1, 0.1] > 0.01: holds
    far = compare("X", "Y", {"X": [0.999] * 4, "Y": [0.899] * 4}, "success_rate")
    assert far.difference == pytest.approx(0.1) and far.verdict == "holds"
    # in metres: 0.05 m apart is below d_min_uav's 0.1 m, 0.2 m is above it
    assert compare("X", "Y", {"X": [1.65] * 3, "Y": [1.6] * 3}, "d_min_uav").verdict == "not distinguishable"
    assert compare("X", "Y", {"X": [1.8] * 3, "Y": [1.6] * 3}, "d_min_uav").verdict == "holds"


def test_the_difference_interval_comes_from_the_bootstrap():
    """X = [0.90, 0.92, 0.94], Y = [0.80, 0.82, 0.84]: the difference of means is 0.10; any
    resample's X mean lies in [0.90, 0.94] and Y's in [0.80, 0.84], so its interval lies within
    [0.06, 0.14], above 0.01: holds (and P = 1, every X seed above every Y seed)."""
    c = compare("X", "Y", {"X": [0.90, 0.92, 0.94], "Y": [0.80, 0.82, 0.84]}, "success_rate")
    assert c.difference == pytest.approx(0.10)
    assert 0.06 - 1e-12 <= c.difference_low < 0.10 < c.difference_high <= 0.14 + 1e-12
    assert c.probability == 1.0 and c.verdict == "holds"


def test_clearly_separated_seeds_hold_and_overlapping_ones_do_not():
    apart = compare("A", "B", {"A": [0.9, 0.92, 0.95, 0.91, 0.93], "B": [0.6, 0.62, 0.65, 0.61, 0.63]}, "success_rate")
    assert (apart.probability, apart.verdict) == (1.0, "holds")
    assert apart.low == 1.0   # every resample keeps every A above every B
    mixed = compare("A", "B", {"A": [0.6, 0.9, 0.7, 0.8, 0.65], "B": [0.62, 0.88, 0.72, 0.78, 0.66]}, "success_rate")
    assert mixed.verdict == "not distinguishable"
    assert mixed.low < 0.5 < mixed.high
    reversed_ = compare("B", "A", {"A": [0.9, 0.92, 0.95], "B": [0.6, 0.62, 0.65]}, "success_rate")
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
    # difference of means 0.91 - 0.98 = -0.070; every resample lies within [-0.09, -0.05], below -0.01
    row = re.search(r"\| Policy3-G above Policy5-G \| 3 / 3 \| 0.00 \[0.00, 0.00\] \| -0.070 \[(\S+), (\S+)\] \| (\w+) \|",
                    table)
    assert row and -0.09 <= float(row[1]) < -0.07 < float(row[2]) <= -0.05 and row[3] == "reversed"


def test_score_distribution_counts_runs_strictly_above_each_level():
    # runs 0.5, 0.8, 0.8, 1.0: above 0.0 all 4; above 0.5 three (0.5 is not above itself);
    # above 0.8 one; above 1.0 none
    levels = np.array([0.0, 0.5, 0.8, 1.0])
    assert score_distribution([0.5, 0.8, 0.8, 1.0], levels).tolist() == [1.0, 0.75, 0.25, 0.0]
    # batched: runs along the last axis, levels first in the answer
    batch = score_distribution(np.array([[0.5, 0.8, 0.8, 1.0], [0.0, 0.0, 1.0, 1.0]]), levels)
    assert batch.shape == (4, 2) and batch[:, 1].tolist() == [0.5, 0.5, 0.5, 0.0]


def test_performance_profile_band_holds_the_curve_and_repeats():
    runs = [0.7, 0.8, 0.85, 0.9, 0.95, 1.0]
    a, b = performance_profile(runs), performance_profile(runs)
    assert np.array_equal(a.low, b.low) and np.array_equal(a.high, b.high)
    assert np.all(a.low <= a.fraction + 1e-12) and np.all(a.fraction <= a.high + 1e-12)
    assert a.fraction[0] == 1.0 and a.fraction[-1] == 0.0          # levels 0 and 1
    assert np.any(a.low < a.high)                                   # six different runs: a real band


def test_summary_and_profile_written_from_a_seeds_csv(tmp_path):
    path = tmp_path / "t_seeds.csv"
    rows = ["policy,extra,success_rate,safe_success_rate,d_min_uav,d_c"]
    for seed in range(4):
        rows += [f"Policy5-G,,{0.96 + seed / 100},0.9,1.7,3.0", f"Policy3-G,,{0.90 + seed / 100},0.8,1.6,3.1"]
    path.write_text("\n".join(rows) + "\n")
    table = summary_table(path)
    # Policy5-G success 0.96, 0.97, 0.98, 0.99: mean 0.975; IQM drops one from each end: 0.975
    assert "| Policy5-G | success_rate | 4 | 0.975 [" in table and "| 0.960-0.990 |" in table
    claims = write_claims(path, tmp_path / "claims.md").read_text()
    assert "## Per policy, over seeds" in claims and "| Policy3-G | d_c | 4 | 3.100 [3.100, 3.100]" in claims
    png = plot_profiles(path, tmp_path / "profile.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_claims_overview_sets_the_paper_beside_each_recipe(tmp_path):
    fast = tmp_path / "fast_seeds.csv"
    rows = ["policy,extra,success_rate,d_min_uav,d_c"]
    for seed in range(3):
        rows += [f"Policy5-G,,{0.99 - seed / 100},1.7,3.0", f"Policy3-G,,{0.90 + seed / 100},1.6,3.1"]
    fast.write_text("\n".join(rows) + "\n")
    table = claims_overview({"fast": fast, "paper recipe": tmp_path / "missing.csv"})
    tangential = next(line for line in table.splitlines() if "tangential" in line)
    # the paper: Policy3-G 0.938 above Policy5-G 0.886 in its Table III; ours: every Policy3-G seed
    # below every Policy5-G seed, so P = 0 and its interval [0, 0]: reversed
    assert re.search(r"\| holds \(1 of 1\) \| reversed: P = 0.00 \[0.00, 0.00\], difference -0.070 \[-0.0\d\d, -0.0\d\d\] "
                     r"\(3 seeds\) \| not published \|$", tangential), tangential
    critic = next(line for line in table.splitlines() if "critic" in line)
    assert "no comparison (policies not trained)" in critic


def test_a_fixed_baseline_score_is_compared_over_the_learned_seeds_alone():
    """Section 11: a deterministic baseline's one score is a constant; P(X > y) is the fraction of X's
    seeds above it (ties half) and both intervals resample X's seeds."""
    from flock_torchrl.report.seeds import compare_fixed

    c = compare_fixed("X", "MA", [0.9, 1.0, 1.0, 1.0, 0.95], 0.8, "success_rate")
    # Every seed above 0.8: P = 1 in every resample; mean 0.97, so the difference is 0.17 and a
    # resample's mean lies between the lowest and highest seed: [0.1, 0.2] less 0.8's offset.
    assert (c.probability, c.low, c.high) == (1.0, 1.0, 1.0)
    assert c.difference == pytest.approx(0.17) and 0.1 - 1e-12 <= c.difference_low <= c.difference_high <= 0.2 + 1e-12
    assert c.verdict == "holds"
    # Two seeds above 1.5 m, two below, one tied: P = (2 + 0.5) / 5; the mean 1.42 m.
    c = compare_fixed("X", "OP", [1.0, 1.2, 1.5, 1.6, 1.8], 1.5, "d_min_uav")
    assert c.probability == pytest.approx(0.5) and c.difference == pytest.approx(-0.08)
    assert c.verdict == "not distinguishable"
    assert compare_fixed("X", "OP", [0.2, 0.3, 0.25], 0.9, "success_rate").verdict == "reversed"
    assert compare_fixed("X", "OP", [1.0, 1.0, 1.0], 1.0, "success_rate").verdict == "not distinguishable"
    assert compare_fixed("X", "OP", [1.0, 1.0], 0.0, "success_rate").verdict == "too few seeds"
