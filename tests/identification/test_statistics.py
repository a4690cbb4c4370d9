"""Launch statistics: rank-sum tests (Tables 6, 8, 9), Tukey outlier rule, aggregate intervals."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from identification import statistics


def _u_by_counting(a, b):
    """Mann-Whitney U of ``a``: pairs with a_i > b_j, ties counting one half."""
    return sum((x > y) + 0.5 * (x == y) for x in a for y in b)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(a=st.lists(st.integers(0, 8), min_size=1, max_size=12), b=st.lists(st.integers(0, 8), min_size=1, max_size=12))
def test_rank_sum_matches_scipy_mannwhitneyu_with_ties(a, b):
    if len(set(a) | set(b)) < 2:
        return  # all values tied: no test
    res = statistics.rank_sum_test(a, b)
    ref = stats.mannwhitneyu(a, b, alternative="two-sided", method="asymptotic", use_continuity=True)
    assert res["U"] == pytest.approx(_u_by_counting(a, b))
    assert res["U"] == pytest.approx(ref.statistic)
    assert res["p"] == pytest.approx(ref.pvalue, rel=1e-9, abs=1e-12)
    # z has the sign of U - n1 n2 / 2 (first group ranked higher -> positive)
    d = res["U"] - len(a) * len(b) / 2
    if res["z"] != 0:
        assert np.sign(res["z"]) == np.sign(d)
    else:
        assert abs(d) <= 0.5  # within the continuity correction


@settings(max_examples=100, deadline=None, derandomize=True)
@given(a=st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=24), b=st.lists(st.floats(-1e3, 1e3), min_size=2,
                                                                           max_size=24))
def test_rank_sum_matches_scipy_on_continuous_values(a, b):
    if len(set(a) | set(b)) < 2:
        return
    res = statistics.rank_sum_test(a, b)
    ref = stats.mannwhitneyu(a, b, alternative="two-sided", method="asymptotic", use_continuity=True)
    assert res["p"] == pytest.approx(ref.pvalue, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("u_target, z_paper, p_paper", [
    (16, -0.240, 0.8102),   # Table 8, sway (every pair) and Table 9, X L3-L4 (z 0.2401)
    (31, 2.0016, 0.0453),   # Table 9, Y L1-L3
    (35, 2.6421, 0.0082),   # Table 9, Y L1-L4
    (34, 2.482, 0.0131),    # Table 9, Y L2-L4 and Z L1-L4
    (18, 0.0, 1.0),          # Table 8, Z L3-L4
])
def test_six_versus_six_reproduces_table_values(u_target, z_paper, p_paper):
    """6 launches per amplitude group: sigma_U = sqrt(6*6*13/12); z = (U - 18 -+ 1/2) / sigma_U."""
    # two groups of six distinct launch values (a random split of 12 values) with the wanted U
    rng = np.random.default_rng(0)
    values = 0.5 + 0.01 * np.arange(12)  # e.g. K_L of twelve launches
    for _ in range(20000):
        perm = rng.permutation(values)
        a, b = perm[:6], perm[6:]
        if _u_by_counting(a, b) == u_target:
            break
    else:
        pytest.fail("no sample found")
    res = statistics.rank_sum_test(a, b)
    assert res["U"] == u_target
    assert abs(res["z"]) == pytest.approx(abs(z_paper), abs=6e-4)
    assert res["p"] == pytest.approx(p_paper, abs=6e-5)
    if u_target == 16:
        assert res["z"] < 0  # first group ranked lower: the sign the tables print
    sigma = math.sqrt(6 * 6 * 13 / 12)
    if u_target != 18:
        assert abs(res["z"]) == pytest.approx((abs(u_target - 18) - 0.5) / sigma, rel=1e-12)


def test_pairwise_tests_between_four_groups():
    rng = np.random.default_rng(1)
    values = np.concatenate([rng.normal(m, 0.1, 6) for m in (1.0, 1.0, 1.5, 2.0)])
    groups = [f"L{k}" for k in (1, 2, 3, 4) for _ in range(6)]
    res = statistics.pairwise_tests(values, groups)
    assert [r["groups"] for r in res] == [["L1", "L2"], ["L1", "L3"], ["L1", "L4"], ["L2", "L3"], ["L2", "L4"],
                                          ["L3", "L4"]]
    p = {tuple(r["groups"]): r["p"] for r in res}
    assert p[("L1", "L4")] < 0.01  # complete separation of 6 vs 6: p = 0.0051 (Table 9's smallest)
    assert p[("L1", "L4")] == pytest.approx(0.0051, abs=1e-4)
    assert p[("L1", "L2")] > 0.05


def test_amplitude_groups_follow_the_protocol_levels():
    lv = statistics.LEVELS["spring"]
    assert statistics.amplitude_groups([0.0098, 0.021, 0.0285, 0.043, -1.0, float("nan")], lv) == \
        ["L1", "L2", "L3", "L4", None, None]
    pend = statistics.LEVELS["pendulum"]
    assert statistics.amplitude_groups([math.radians(2.4), math.radians(9.5)], pend) == ["L1", "L3"]


def test_tukey_fences_quartiles():
    lo, hi = statistics.tukey_fences(np.arange(1, 9), k=1.5)  # Q1 2.75, Q3 6.25 (linear interpolation)
    assert (lo, hi) == pytest.approx((2.75 - 1.5 * 3.5, 6.25 + 1.5 * 3.5))
    lo3, hi3 = statistics.tukey_fences([1, 2, 3, 4, np.nan, 5, 6, 7, 8], k=3.0)
    assert (lo3, hi3) == pytest.approx((2.75 - 3 * 3.5, 6.25 + 3 * 3.5))


def test_far_out_fences_rarely_flag_clean_axes():
    """The documented false-alarm rates: 3 IQR fences on 24 normal deviations ~1.5 %, 1.5 IQR on 6 ~27 %."""
    rng = np.random.default_rng(2)
    far = np.mean([_any_outside(rng.standard_normal(24), 3.0) for _ in range(4000)])
    near = np.mean([_any_outside(rng.standard_normal(6), 1.5) for _ in range(4000)])
    assert far < 0.03
    assert 0.2 < near < 0.35


def _any_outside(x, k):
    lo, hi = statistics.tukey_fences(x, k)
    return bool(np.any((x < lo) | (x > hi)))


def test_outlier_rule_flags_a_bad_launch_but_not_an_amplitude_trend():
    table, groups = {}, {}
    scatter = stats.norm.ppf((np.arange(6) + 0.5) / 6)  # six launches spread like normal draws
    for g, level in enumerate((1.6, 1.4, 1.3, 1.25)):  # C_D falling with Reynolds number (Fig. 18)
        for k in range(6):
            name = f"L{g + 1}_r{k}"
            table[name] = {"CD": level + 0.02 * scatter[(k + g) % 6], "CD_se": 0.02}
            groups[name] = f"L{g + 1}"
    assert statistics.outlier_reasons(table, ["CD"], groups=groups) == {}
    table["L3_r2"]["CD"] = 2.5  # a bad launch
    reasons = statistics.outlier_reasons(table, ["CD"], groups=groups)
    assert list(reasons) == ["L3_r2"]
    assert "CD = 2.5" in reasons["L3_r2"] and "Tukey" in reasons["L3_r2"]
    # without the grouping the trend itself would look like scatter, the bad launch still stands out
    assert "L3_r2" in statistics.outlier_reasons(table, ["CD"])
    # too few launches: nothing rejected
    few = dict(list(table.items())[:4])
    assert statistics.outlier_reasons(few, ["CD"], groups=groups) == {}


def test_aggregate_without_standard_errors_is_the_t_interval():
    x = np.array([0.81, 0.83, 0.80, 0.84, 0.82, 0.79])
    agg = statistics.aggregate(x)
    lo, hi = stats.t.interval(0.95, x.size - 1, loc=x.mean(), scale=stats.sem(x))
    assert agg["value"] == pytest.approx(x.mean())
    assert agg["ci95"] == pytest.approx([lo, hi])


def test_aggregate_weighted_mean_and_single_launch():
    v, se = [1.0, 1.1, 0.95], [0.1, 0.2, 0.1]
    agg = statistics.aggregate(v, se)
    w = 1 / np.square(se)
    assert agg["value"] == pytest.approx(np.sum(w * v) / np.sum(w))
    assert agg["birge_ratio"] == 1.0  # launches agree within their errors: no inflation
    q = stats.t.ppf(0.975, 2)
    assert agg["ci95"] == pytest.approx([agg["value"] - q / math.sqrt(w.sum()), agg["value"] + q / math.sqrt(w.sum())])
    one = statistics.aggregate([2.0], [0.1])
    assert one["ci95"] == pytest.approx([2.0 - 1.96 * 0.1, 2.0 + 1.96 * 0.1])
    assert statistics.aggregate([np.nan], [0.1])["n"] == 0


def test_birge_inflation_restores_coverage_when_launches_scatter_beyond_their_errors():
    """Launch-to-launch variation 3x the fits' own standard errors: inflated intervals still cover ~95 %."""
    rng = np.random.default_rng(4)
    truth, hits, naive = 1.0, [], []
    for _ in range(2000):
        se = rng.uniform(0.005, 0.02, 24)
        v = truth + rng.normal(0, 3 * se)
        agg = statistics.aggregate(v, se)
        hits.append(agg["ci95"][0] <= truth <= agg["ci95"][1])
        w = 1 / se ** 2
        m, e = np.sum(w * v) / np.sum(w), 1 / math.sqrt(np.sum(w))
        naive.append(abs(m - truth) <= 1.96 * e)
    assert 0.93 <= np.mean(hits) <= 0.97
    assert np.mean(naive) < 0.6  # what the un-inflated weighted mean would claim
