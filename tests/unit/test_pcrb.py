"""The posterior Cramér–Rao bound: Fisher information of each noise model, the recursion, and
the floor it sets under every filter.
"""

import math

import numpy as np
import pytest

from navlab import pcrb
from navlab.cli import main
from navlab.experiment import ExperimentSpec, run_experiment
from navlab.noise import fisher as FI
from navlab.noise import make_outliers
from navlab.tables import summary_rows


def _fisher_by_grid(logpdf, half_width: float, n: int = 2_000_001) -> float:
    """∫ p (d log p / du)² du by the trapezoid rule on a fine grid, the derivative by central
    differences of log p: independent of the score formula and of the adaptive quadrature.
    """
    u = np.linspace(-half_width, half_width, n)
    lp = logpdf(u)
    score = np.gradient(lp, u)
    return float(np.trapezoid(np.exp(lp) * score**2, u))


def _mixture_logpdf(alpha, kappa):
    def f(u):
        a = np.log1p(-alpha) - 0.5 * u**2 - 0.5 * np.log(2 * np.pi)
        b = np.log(alpha) - np.log(kappa) - 0.5 * (u / kappa) ** 2 - 0.5 * np.log(2 * np.pi)
        return np.logaddexp(a, b)

    return f


@pytest.mark.parametrize(("alpha", "kappa"), [(0.1, 10.0), (0.05, 3.0), (0.3, 30.0), (0.01, 100.0)])
def test_contaminated_gaussian_fisher_matches_an_independent_integral(alpha, kappa):
    got = FI.mixture(alpha, kappa)
    ref = _fisher_by_grid(_mixture_logpdf(alpha, kappa), 40.0 * kappa)
    assert got == pytest.approx(ref, rel=2e-5)
    # Gaussian is the least informative density of its variance; contamination loses information
    assert 1.0 / ((1 - alpha) + alpha * kappa**2) < got < 1.0


def test_fisher_limits_and_student_t_closed_form():
    assert FI.mixture(0.0, 10.0) == 1.0
    assert FI.mixture(0.2, 1.0) == pytest.approx(1.0, abs=1e-9)  # κ = 1: no contamination at all
    assert FI.mixture(1.0, 4.0) == pytest.approx(1 / 16)
    nu = 3.0
    t_logpdf = lambda u: (  # noqa: E731
        math.lgamma((nu + 1) / 2)
        - math.lgamma(nu / 2)
        - 0.5 * math.log(nu * math.pi)
        - (nu + 1) / 2 * np.log1p(u**2 / nu)
    )
    assert FI.student_t(nu) == pytest.approx(_fisher_by_grid(t_logpdf, 2000.0, 4_000_001), rel=1e-4)


def test_outlier_models_give_per_entry_information():
    std = np.full((11, 2), 2.0)
    assert np.allclose(make_outliers("none").fisher(std), 0.25)
    J = make_outliers("mixture", {"contamination": 0.1, "scale": 10.0, "channels": [1]}).fisher(std)
    assert np.allclose(J[:, 0], 0.25) and np.allclose(J[:, 1], FI.mixture(0.1, 10.0) / 4)
    J = make_outliers("isolated", {"start": 2, "stop": 8, "every": 3, "scale": 4.0}).fisher(std)
    hit = np.zeros((11, 2), dtype=bool)
    hit[[2, 5, 8], 0] = True
    assert np.allclose(J[hit], 0.25 / 17) and np.allclose(J[~hit], 0.25)


@pytest.mark.parametrize(
    ("filt", "schedule"), [("kf", "constant"), ("oracle-kf", "step"), ("oracle-kf", "ramp")]
)
def test_without_outliers_the_bound_is_the_kalman_filters_covariance(filt, schedule):
    # Gaussian noise, linear model: the PCRB recursion is the KF's covariance recursion (the
    # oracle KF is told the true R(t) of a changing schedule; the plain KF's R is right when
    # the schedule is constant)
    spec = ExperimentSpec(scenario="cv2d", filters=(filt,), runs=3, outliers="none", noise_schedule=schedule)
    b = pcrb.bound(spec)
    res = run_experiment(spec)
    P = res.runs[filt].P_diag[0]
    assert b.kind == "linear"
    assert np.allclose(np.einsum("kii->ki", b.P), P, rtol=1e-9, atol=0)


def test_with_outliers_the_bound_lies_above_the_gaussian_one_of_the_nominal_sigma():
    spec = ExperimentSpec(scenario="cv2d", filters=("kf",), runs=3)
    clean = pcrb.bound(spec.replace(outliers="none"))
    dirty = pcrb.bound(spec.replace(outliers="mixture"))
    assert (np.einsum("kii->k", dirty.P)[1:] > np.einsum("kii->k", clean.P)[1:]).all()


CASES = [
    ("cv2d", "mixture", ("kf", "chi2-kf", "huber-kf", "vb-akf", "hakf", "sage-husa", "student-t-kf")),
    ("cv2d", "student-t", ("kf", "chi2-kf", "huber-kf", "student-t-kf")),
    ("cv2d", "isolated", ("kf", "chi2-kf", "irakf")),
    ("gps-ins-pseudorange", "mixture", ("ekf", "vb-ekf", "huber-kf")),
]


@pytest.mark.slow
@pytest.mark.parametrize(("scenario", "outliers", "filters"), CASES)
def test_no_filter_goes_below_the_floor_beyond_its_interval(scenario, outliers, filters):
    spec = ExperimentSpec(
        scenario=scenario, filters=(*filters, "oracle-kf"), runs=200, seed=5, outliers=outliers
    )
    res = run_experiment(spec)
    df = summary_rows(res)
    groups = [g for g in res.data.groups if f"pcrb_{g}" in set(df.metric)]
    assert groups
    for g in groups:
        fl = df[df.metric == f"pcrb_{g}"].iloc[0]
        floor_lo = fl.ci_lo if np.isfinite(fl.ci_lo) else fl.value
        for k in filters:
            r = df[(df["filter"] == k) & (df.metric == f"rmse_{g}")].iloc[0]
            assert r.ci_hi >= floor_lo, (k, g, r.value, fl.value)


def test_run_json_carries_pcrb_and_gap_rows_with_intervals(capsys):
    argv = "run --scenario cv2d --filters kf,huber-kf,oracle-kf --runs 30 --format json"
    rc = main(argv.split())
    out, _ = capsys.readouterr()
    assert rc == 0
    import json

    rows = json.loads(out)
    floor = [r for r in rows if r["metric"] == "pcrb_pos"]
    gaps = [r for r in rows if r["metric"] == "gap_pos"]
    assert len(floor) == 1 and floor[0]["value"] > 0
    assert {r["filter"] for r in gaps} == {"kf", "huber-kf", "oracle-kf"}
    assert all(r["ci_lo"] < r["value"] < r["ci_hi"] for r in gaps)


def test_monte_carlo_bound_has_an_interval_and_a_scenario_without_a_model_has_none():
    spec = ExperimentSpec(scenario="gps-ins-pseudorange", filters=("ekf",), runs=20)
    b = pcrb.bound(spec)
    assert b.kind == "monte-carlo" and b.runs == 20
    v, lo, hi = b.floor((0, 1, 2), np.arange(b.P.shape[0]) >= 1)
    assert lo < v < hi
    rtk = ExperimentSpec(scenario="gps-ins-rtk", filters=("kf",), runs=2)
    assert pcrb.bound(rtk) is None
    assert "gps-ins-rtk" in pcrb.why_none(rtk)


def test_the_error_chart_draws_the_floor_per_epoch_when_asked():
    from navlab.ui import figures as F

    spec = ExperimentSpec(scenario="cv2d", filters=("kf", "oracle-kf"), runs=4, epochs=30)
    res = run_experiment(spec)
    assert "floor (PCRB)" not in [t.name for t in F.error_vs_time(res, "pos").data]
    line = next(t for t in F.error_vs_time(res, "pos", floor=True).data if t.name == "floor (PCRB)")
    P = pcrb.bound(spec).P
    want = np.sqrt(P[:, 0, 0] + P[:, 2, 2])
    assert np.allclose(line.y, want, rtol=1e-6)


def test_a_filter_without_an_rmse_has_no_gap_number_not_nan(monkeypatch):
    """A filter whose every run diverged printed 'Gap (RMSE / floor): … nan×'."""
    from navlab.filters.kalman import KF
    from navlab.pcrb import floor_text

    update = KF.update

    def nan_update(self, model, state, k, z, side):
        st, out = update(self, model, state, k, z, side)
        return st._replace(x=st.x * np.nan), out

    monkeypatch.setattr(KF, "update", nan_update)
    res = run_experiment(ExperimentSpec(filters=("kf", "chi2-kf"), runs=3, epochs=10))
    text = floor_text(res, "pos", markdown=False)
    assert "KF — (no RMSE: no run judged)" in text and "nan" not in text
