"""The statistics behind every interval: coverage over repeated small Monte Carlo experiments with a
known true value, paired differences, Holm, the bootstrap/delta switch (docs/STATISTICS.md §2–3)."""

from __future__ import annotations

import numpy as np
import pytest

from navlab import stats as S
from navlab.experiment import ExperimentSpec, plan, run_filters
from navlab.linalg import predict_cov

SETS, PER_SET = 200, 20  # 200 repeats of a 20-run experiment


@pytest.fixture(scope="module")
def kf_runs():
    """4000 runs of the plain KF on cv2d with the nominal noise: the KF is optimal and
    consistent there, so its error covariance is its own P_k — the truth is known in closed form."""
    spec = ExperimentSpec(
        filters=("kf",), runs=SETS * PER_SET, epochs=40, outliers="none", noise_schedule="constant"
    )
    p = plan(spec)
    data = p.scenario.simulate(p.schedule, p.outliers, list(range(spec.runs)), spec.seed)
    fr = run_filters(data, p.filters)["kf"]
    # the KF's covariance is the same in every run: recompute it by the Riccati recursion
    m = data.model
    P = data.P0.copy()
    Ps = [P]
    H, R = m.H(None, 1), m.R0
    for k in range(1, data.K + 1):
        P = predict_cov(m.F(k), P, m.Q(k))
        Kg = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        I_KH = np.eye(4) - Kg @ H
        P = I_KH @ P @ I_KH.T + Kg @ R @ Kg.T
        Ps.append(P)
    Ps = np.array(Ps)
    return data, fr, Ps


def _coverage(make, truth, n_sets=SETS, per_set=PER_SET):
    hits, methods = 0, set()
    for s in range(n_sets):
        sl = slice(s * per_set, (s + 1) * per_set)
        est = make(sl)
        e = S.Resampler(per_set, seed=s).estimate(est)
        methods.add(e.method)
        hits += e.lo <= truth <= e.hi
    return hits / n_sets, methods


def test_pooled_rmse_interval_covers_the_true_rmse(kf_runs):
    data, fr, Ps = kf_runs
    W = data.window
    e2 = ((fr.x[..., [0, 2]] - data.x_true[..., [0, 2]]) ** 2).sum(-1)[:, W]
    truth = float(np.sqrt(np.mean(Ps[W][:, 0, 0] + Ps[W][:, 2, 2])))
    cov, methods = _coverage(lambda sl: S.Ratio(e2[sl].sum(1), np.full(PER_SET, W.sum()), sqrt=True), truth)
    print(f"pooled RMSE: 95 % bootstrap interval covered the true value in {100 * cov:.1f} % of {SETS}")
    # (the plain percentile interval, without the small-sample expansion, covers ≈ 89 % here)
    assert methods == {"bootstrap"}
    assert cov >= 0.90


def test_mean_of_rmse_and_anees_intervals_cover(kf_runs):
    data, fr, Ps = kf_runs
    W = data.window
    e2 = ((fr.x[..., [0, 2]] - data.x_true[..., [0, 2]]) ** 2).sum(-1)[:, W]
    truth = float(np.mean(np.sqrt(Ps[W][:, 0, 0] + Ps[W][:, 2, 2])))
    cov, _ = _coverage(lambda sl: S.MeanSqrtRatio(e2[sl]), truth)
    print(f"mean of per-epoch RMSE: coverage {100 * cov:.1f} %")
    assert cov >= 0.90
    nees = fr.nees[:, W]
    cov, _ = _coverage(lambda sl: S.Ratio(nees[sl].sum(1), np.full(PER_SET, W.sum())), 4.0)
    print(f"ANEES (consistent KF, true value n = 4): coverage {100 * cov:.1f} %")
    assert cov >= 0.90


def test_delta_method_at_many_runs_covers_and_agrees_with_the_bootstrap():
    rng = np.random.default_rng(7)
    n, truth = 1500, np.sqrt(2.0)  # per-run mean of 50 squared N(0, 2) errors: true RMSE √2
    hits = 0
    for s in range(200):
        sse = (rng.normal(0, np.sqrt(2.0), (n, 50)) ** 2).sum(1)
        est = S.Ratio(sse, np.full(n, 50.0), sqrt=True)
        e = S.Resampler(n, seed=s).estimate(est)
        assert e.method == "delta"
        hits += e.lo <= truth <= e.hi
    print(f"delta method, {n} runs: coverage {hits / 2:.1f} %")
    assert hits / 200 >= 0.90
    # on one sample the delta and the bootstrap intervals agree closely
    boot = S.Resampler(n, seed=1)
    t = boot.replicates(est)
    lo, hi = np.quantile(t, [0.025, 0.975])
    assert e.lo == pytest.approx(lo, rel=0.01) and e.hi == pytest.approx(hi, rel=0.01)


def test_paired_difference_is_much_narrower_than_unpaired_and_covers():
    rng = np.random.default_rng(3)
    n, hits, widths = 40, 0, []
    for s in range(200):
        common = rng.gamma(2.0, 50.0, n)  # run-to-run variation both filters share
        a = common + rng.normal(1.0, 1.0, n)  # A is worse by 1 on average
        b = common
        ea, eb = S.Ratio(a, np.ones(n)), S.Ratio(b, np.ones(n))
        rs = S.Resampler(n, seed=s)
        c = rs.compare(ea, eb)
        hits += c.lo <= 1.0 <= c.hi
        ia, ib = rs.estimate(ea), rs.estimate(eb)
        widths.append(((c.hi - c.lo), (ia.hi - ia.lo) + (ib.hi - ib.lo)))
    print(f"paired Δ: coverage {hits / 2:.1f} %")
    assert hits / 200 >= 0.90
    paired, unpaired = np.median(np.array(widths), axis=0)
    assert paired < 0.2 * unpaired  # pairing removes the shared variation


@pytest.mark.slow
def test_quantile_interval_covers_the_median():
    rng = np.random.default_rng(11)
    hits = 0
    for s in range(200):
        # runs with their own offset: values inside a run are correlated
        v = rng.exponential(1.0, (30, 1)) + rng.exponential(1.0, (30, 60))
        e = S.Resampler(30, seed=s).estimate(S.Quantile(v, 0.5))
        hits += e.lo <= TRUE_MEDIAN_SUM_EXP2 <= e.hi
    print(f"pooled median: coverage {hits / 2:.1f} %")
    assert hits / 200 >= 0.90


# median of the sum of two unit exponentials (Gamma(2, 1)): solves 1 − (1 + x) e^{−x} = 1/2
TRUE_MEDIAN_SUM_EXP2 = 1.6783469900166608


def test_p_value_floor_identical_filters_and_too_few_runs():
    rng = np.random.default_rng(0)
    a = rng.random(50)
    rs = S.Resampler(50, seed=0)
    far = rs.compare(S.Ratio(a + 10, np.ones(50)), S.Ratio(a, np.ones(50)))
    # no resample on the other side of 0: floored at the bootstrap's resolution, never 0
    assert far.at_floor and 1 / S.N_BOOT < far.p_value < 0.01 and far.p_text.startswith("p < ")
    same = rs.compare(S.Ratio(a, np.ones(50)), S.Ratio(a, np.ones(50)))
    assert same.value == 0 and same.p_value == 1.0 and same.lo == same.hi == 0
    few = S.Resampler(5).estimate(S.Ratio(a[:5], np.ones(5)))
    assert not few.has_ci and few.note == S.TOO_FEW and np.isfinite(few.value)


def test_resampling_is_deterministic_and_shared():
    r1, r2 = S.Resampler(30, seed=4), S.Resampler(30, seed=4)
    b1, b2 = list(r1.blocks()), list(r2.blocks())
    assert all(np.array_equal(x, y) for x, y in zip(b1, b2, strict=True))
    W = np.concatenate(b1)
    assert W.shape == (S.N_BOOT, 30) and (W.sum(1) == 30).all()
    assert not np.array_equal(W, np.concatenate(list(S.Resampler(30, seed=5).blocks())))


def test_interval_and_test_agree():
    """p < 0.05 exactly when the 95 % interval of Δ excludes 0 (same expansion for both)."""
    rng = np.random.default_rng(5)
    for shift in (0.0, 0.2, 0.4, 0.6, 1.0):
        a = rng.normal(0, 1, 25)
        b = a + shift + rng.normal(0, 1, 25)
        c = S.Resampler(25, seed=1).compare(S.Ratio(b, np.ones(25)), S.Ratio(a, np.ones(25)))
        excludes = c.lo > 0 or c.hi < 0
        assert excludes == (c.p_value < 0.05) or abs(c.p_value - 0.05) < 0.005


def test_holm_step_down():
    adj = S.holm({"a": 0.01, "b": 0.04, "c": 0.03, "d": float("nan")})
    assert adj["a"] == pytest.approx(0.03)  # 3 × 0.01
    assert adj["c"] == pytest.approx(0.06)  # 2 × 0.03
    assert adj["b"] == pytest.approx(0.06)  # max(1 × 0.04, previous 0.06)
    assert np.isnan(adj["d"])


def test_sig3_and_mean_ci():
    assert S.sig3(1.23456) == "1.23" and S.sig3(0.0123456) == "0.0123" and S.sig3(123456) == "1.23e+05"
    assert S.sig3(float("nan")) == ""
    e = S.mean_ci([1.0, 2.0, 3.0])
    assert e.value == 2.0 and e.lo < 2.0 < e.hi


def test_influence_values_are_not_kept_for_very_many_runs(monkeypatch):
    """Above PSI_CACHE_RUNS runs ψ is recomputed at each use (memory), with the same interval."""
    rng = np.random.default_rng(3)
    num, den = rng.gamma(2.0, size=3000), np.full(3000, 10.0)
    kept = S.Ratio(num, den, sqrt=True)
    ci_kept = S.Resampler(3000, seed=1).estimate(kept)
    assert "_psi" in kept.__dict__
    monkeypatch.setattr(S, "PSI_CACHE_RUNS", 1000)
    fresh = S.Ratio(num, den, sqrt=True)
    ci_fresh = S.Resampler(3000, seed=1).estimate(fresh)
    assert "_psi" not in fresh.__dict__
    assert (ci_fresh.value, ci_fresh.lo, ci_fresh.hi) == (ci_kept.value, ci_kept.lo, ci_kept.hi)


def _paired_cases():
    """Paired comparisons of every kind of statistic: smooth (pooled RMSE), a maximum and a
    quantile (bias corrected, no acceleration), small and large shifts, 12 to 100 runs."""
    rng = np.random.default_rng(0)
    for i in range(300):
        n = int(rng.choice([12, 20, 40, 100]))
        K = int(rng.choice([5, 30]))
        shift = rng.choice([0.0, 0.05, 0.1, 0.2, 0.5, 1.0])
        base = rng.gamma(2.0, size=(n, K))
        a = base * (1 + shift) + 0.3 * rng.gamma(2.0, size=(n, K))
        b = base + 0.3 * rng.gamma(2.0, size=(n, K))
        kind = ("max", "rmse", "median")[i % 3]
        if kind == "max":
            ea, eb = S.MaxSqrtRatio(a), S.MaxSqrtRatio(b)
        elif kind == "rmse":
            ea, eb = (S.Ratio(x.sum(1), np.full(n, float(K)), sqrt=True) for x in (a, b))
        else:
            ea, eb = S.Quantile(a, 0.5), S.Quantile(b, 0.5)
        yield i, kind, S.Resampler(n, seed=i).compare(ea, eb, relative=bool(i % 2))


def test_p_below_5_percent_exactly_when_the_interval_excludes_0():
    """One bootstrap inverted for both (issue 25, item 5): p < 0.05 ⇔ 0 outside the 95 % interval,
    for every paired statistic — the maximum of the per-epoch RMSE with its bias correction too,
    where a p computed from the share of resamples below 0 read 0.96 beside [0.47, 0.62]."""
    seen = set()
    for i, kind, c in _paired_cases():
        excludes = c.lo > 0 or c.hi < 0
        assert excludes == (c.p_value < S.ALPHA), (i, kind, c)
        if c.at_floor:  # no resample on the other side of 0: a bound, and below 0.05
            assert excludes and c.p_text.startswith("p < ")
        seen.add((kind, excludes, c.at_floor))
    assert {("max", True, True), ("max", False, False), ("rmse", True, False)} <= seen


def test_holm_keeps_the_bound_of_a_floored_p():
    adj, bound = S.holm_bounds({"a": 0.001, "b": 0.04, "c": 0.03}, {"a": True, "b": False, "c": False})
    assert adj["a"] == pytest.approx(0.003) and bound["a"]  # 3 × a bound is a bound
    assert adj["c"] == pytest.approx(0.06) and not bound["c"]
    assert S.format_p(adj["a"], bound["a"]) == "p < 0.003"


def test_a_p_value_is_never_rounded_onto_alpha():
    """Two decimals put 0.0496 ("better") and 0.0504 ("indistinguishable") both at "p = 0.05"."""
    assert round(S.ALPHA, 12) == 0.05
    assert S.format_p(0.0496) == "p = 0.0496" and S.format_p(0.0504) == "p = 0.0504"
    assert S.format_p(0.04999) == "p = 0.04999" and S.format_p(0.05) == "p = 0.05"
    assert S.format_p(0.123) == "p = 0.12" and S.format_p(0.0123) == "p = 0.01"
    assert S.format_p(0.00123) == "p = 0.0012"


def test_a_lost_run_is_a_loss_for_its_filter_whatever_the_share():
    """Issue 25, item 3: the lost runs are scored as the worst per-run value of the pair (the
    composite strategy), so leaving out the worst runs of A can never make A look better."""
    rng = np.random.default_rng(2)
    n = 100
    b = rng.gamma(4.0, size=n)
    a = b * 1.1 + 0.05 * rng.gamma(2.0, size=n)  # A worse in every run
    lost = np.zeros(n, dtype=bool)
    lost[np.argsort(a - b)[-5:]] = True  # A loses its 5 worst runs (5 %)
    a_nan = np.where(lost, np.nan, a)
    ones = np.ones(n)
    ea, eb = S.with_losses(S.Ratio(a_nan, ones), S.Ratio(b, ones), lost, np.zeros(n, bool), 1)
    assert np.isfinite(ea.num).all() and (ea.num[lost] == max(a[~lost].max(), b.max())).all()
    c = S.Resampler(n, seed=0).compare(ea, eb)
    assert c.value > 0 and c.lo > 0 and c.p_value < S.ALPHA  # still worse
