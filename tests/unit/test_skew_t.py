"""The skew-t VB KF (§11): its limits, the exact one-channel posterior, and the sign of the skewness."""

from __future__ import annotations

import numpy as np
import pytest
from linmodels import random_model, side
from scipy import integrate, stats

from navlab.errors import NavlabError
from navlab.filters import make_filter
from navlab.filters.base import LinearModel
from navlab.filters.reference import REFERENCES
from navlab.filters.skew_t import skew_t_logpdf, truncated_normal_moments


def _run(key, model, x0, P0, z, params=None):
    """The filter over z (B, K+1, m) from (x0, P0); the posterior means (K, B, n) and covariances."""
    f = make_filter(key, params or {})
    st = f.init(model, x0, P0)
    xs, Ps = [], []
    for k in range(1, z.shape[1]):
        st = f.predict(model, st, k)
        st, out = f.update(model, st, k, z[:, k], side(*z[:, k].shape))
        xs.append(out.x)
        Ps.append(np.broadcast_to(out.P, (z.shape[0], *np.shape(out.P)[-2:])))
    return np.array(xs), np.array(Ps)


def _linear_data(seed, n=3, m=3, K=15, B=4, heavy=True):
    rng = np.random.default_rng(seed)
    F, Q, H, R = random_model(rng, n, m)
    R = np.diag(np.diag(R))  # the skew-t KF models each channel on its own
    model = LinearModel(F, Q, H, R)
    x = np.zeros((B, n))
    z = np.full((B, K + 1, m), np.nan)
    for k in range(1, K + 1):
        x = x @ F.T + rng.multivariate_normal(np.zeros(n), Q, B)
        e = rng.standard_normal((B, m)) * np.sqrt(np.diag(R))
        if heavy:  # one-sided NLOS-like excess on some channels
            e += np.where(rng.random((B, m)) < 0.2, rng.exponential(10.0, (B, m)), 0.0)
        z[:, k] = x @ H.T + e
    return model, np.zeros((B, n)), np.eye(n), z


def _skewed(model):
    """``model`` with every channel marked one-sided (frozen dataclass)."""
    object.__setattr__(model, "positive_skew", np.ones(model.m, dtype=bool))
    return model


def test_a_model_that_marks_no_channel_gets_no_skew():
    """Unmarked channels are symmetric (Δ = 0): the same estimates as δ = 0."""
    model, x0, P0, z = _linear_data(5)
    xs, Ps = _run("skew-t-kf", model, x0, P0, z, {"delta": 2.0})
    x0_, P0_ = _run("skew-t-kf", model, x0, P0, z, {"delta": 0.0})
    np.testing.assert_array_equal(xs, x0_)
    np.testing.assert_array_equal(Ps, P0_)
    xk, _ = _run("skew-t-kf", _skewed(model), x0, P0, z, {"delta": 2.0})
    assert np.abs(xk - xs).max() > 1e-3  # marked, the skew does act


def test_delta_zero_dof_infinite_is_the_kf():
    model, x0, P0, z = _linear_data(1)
    xs, Ps = _run("skew-t-kf", model, x0, P0, z, {"delta": 0.0, "dof": 1e15, "iters": 3})
    xk, Pk = _run("kf", model, x0, P0, z)
    sig = np.sqrt(np.diagonal(Pk, axis1=-2, axis2=-1))
    assert np.abs(xs - xk).max() / sig.min() < 1e-9
    np.testing.assert_allclose(Ps, Pk, rtol=1e-9, atol=1e-12)


def test_delta_zero_one_channel_is_the_student_t_kf():
    """m = 1: the per-channel Student-t (δ = 0) is the multivariate one (§1.6) with the same ν, N."""
    model, x0, P0, z = _linear_data(2, n=2, m=1)
    for dof, iters in ((2.0, 1), (4.0, 5)):
        xs, Ps = _run("skew-t-kf", model, x0, P0, z, {"delta": 0.0, "dof": dof, "iters": iters})
        xt, Pt = _run("student-t-kf", model, x0, P0, z, {"dof": dof, "iters": iters})
        np.testing.assert_allclose(xs, xt, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(Ps, Pt, rtol=1e-10, atol=1e-12)
    xs5, _ = _run("skew-t-kf", model, x0, P0, z, {"delta": 0.0, "dof": 4.0, "iters": 5})
    xk, _ = _run("kf", model, x0, P0, z)
    assert np.abs(xs5 - xk).max() > 1e-2  # the data are heavy-tailed: not vacuously the KF


def _exact_skew_normal_posterior(z, p, R, Delta):
    """Mean and variance of x | z for x ~ N(0, p), z = x + e, e skew-normal (Δu + ε), by quadrature."""
    noise = stats.skewnorm(Delta / np.sqrt(R), scale=np.sqrt(R + Delta**2))
    dens = lambda x: stats.norm.pdf(x, scale=np.sqrt(p)) * noise.pdf(z - x)  # noqa: E731
    lo, hi = -12 * np.sqrt(p) + min(z, 0.0), 12 * np.sqrt(p) + max(z, 0.0)
    Z = integrate.quad(dens, lo, hi, epsabs=0, epsrel=1e-12, limit=400)[0]
    m1 = integrate.quad(lambda x: x * dens(x), lo, hi, epsabs=0, epsrel=1e-12, limit=400)[0] / Z
    m2 = integrate.quad(lambda x: (x - m1) ** 2 * dens(x), lo, hi, epsabs=0, epsrel=1e-12, limit=400)[0] / Z
    return m1, m2


@pytest.mark.parametrize("zval", [-4.0, -1.0, 0.5, 3.0, 8.0])
def test_one_channel_skew_normal_is_the_exact_posterior(zval):
    """ν → ∞ (λ = 1), one channel: the one EP site is exact, so x⁺ and P⁺ are the true posterior's
    mean and variance under skew-normal noise (scipy.stats.skewnorm, an independent density)."""
    p, R, delta = 2.0, 0.5, 1.5
    model = _skewed(LinearModel(np.eye(1), np.zeros((1, 1)), np.eye(1), R * np.eye(1)))
    f = make_filter("skew-t-kf", {"delta": delta, "dof": 1e15, "iters": 3})
    st = f.init(model, np.zeros((1, 1)), p * np.eye(1))
    _, out = f.update(model, st, 1, np.array([[zval]]), side(1, 1))
    m1, v1 = _exact_skew_normal_posterior(zval, p, R, delta * np.sqrt(R))
    assert out.x[0, 0] == pytest.approx(m1, rel=1e-7, abs=1e-9)
    assert np.asarray(out.P).reshape(-1)[0] == pytest.approx(v1, rel=1e-7)


def test_long_range_is_explained_short_range_is_not():
    """The sign: a range 6σ too long moves the fix less than one 6σ too short (a flipped Δ would
    reverse the inequality; the exact values are pinned by the quadrature test above)."""
    model = _skewed(LinearModel(np.eye(1), np.zeros((1, 1)), np.eye(1), np.eye(1)))
    f = make_filter("skew-t-kf", {"delta": 2.0, "dof": 5.0})
    st = f.init(model, np.zeros((2, 1)), 1.0 * np.eye(1))
    _, out = f.update(model, st, 1, np.array([[6.0], [-6.0]]), side(2, 1))
    up, down = out.x[0, 0], out.x[1, 0]
    assert 0.0 < up < abs(down) - 0.2 and down < 0.0
    prior_excess = 2.0 * np.sqrt(2.0 / np.pi)  # E[Δ u] a priori (Δ = δ σ = 2, λ = 1)
    assert out.stats["excess"][0, 0] > 3.0 and out.stats["excess"][1, 0] < 0.6 * prior_excess


def test_fast_equals_reference_with_skewed_and_symmetric_channels():
    model, x0, P0, z = _linear_data(3, n=4, m=4, K=12, B=3)
    object.__setattr__(model, "positive_skew", np.array([True, False, True, True]))  # frozen dataclass
    z[1, 5, 2] = np.nan
    params = {"delta": 1.5, "dof": 4.0, "iters": 6, "r_scale": 2.0}
    xs, Ps = _run("skew-t-kf", model, x0, P0, z, params)
    f = make_filter("skew-t-kf", params)
    for b in range(z.shape[0]):
        tr = REFERENCES["skew-t-kf"](model, x0[b], P0, z[b], None, f.params)
        np.testing.assert_allclose(xs[:, b], tr.x, rtol=1e-8, atol=1e-9)
        np.testing.assert_allclose(Ps[:, b], tr.P, rtol=1e-8, atol=1e-11)


def test_truncated_normal_moments_match_scipy():
    mu = np.array([-200.0, -40.0, -5.0, -0.3, 0.0, 2.0, 30.0])
    var = np.array([1.0, 4.0, 0.25, 1.0, 9.0, 1.0, 2.0])
    E, V = truncated_normal_moments(mu, var)
    sd = np.sqrt(var)
    tn = stats.truncnorm(-mu / sd, np.inf, loc=mu, scale=sd)
    np.testing.assert_allclose(E, tn.mean(), rtol=1e-6)
    np.testing.assert_allclose(V, tn.var(), rtol=1e-4)


def test_logpdf_limits():
    e = np.linspace(-6.0, 12.0, 37)
    R, Delta = 0.7, 1.3
    sn = stats.skewnorm(Delta / np.sqrt(R), scale=np.sqrt(R + Delta**2))
    np.testing.assert_allclose(skew_t_logpdf(e, R, Delta, 1e8), sn.logpdf(e), rtol=0, atol=1e-5)
    # ν as the KF limit sets it (1e15): no cancellation in the Gamma-function ratio
    np.testing.assert_allclose(skew_t_logpdf(e, R, Delta, 1e15), sn.logpdf(e), rtol=0, atol=1e-9)
    np.testing.assert_allclose(
        skew_t_logpdf(e, R, 0.0, 3.0), stats.t(3.0, scale=np.sqrt(R)).logpdf(e), rtol=1e-10
    )
    dens = lambda v: np.exp(skew_t_logpdf(v, R, Delta, 3.0))  # noqa: E731
    assert integrate.quad(dens, -np.inf, np.inf)[0] == pytest.approx(1.0, rel=1e-7)


def test_correlated_R_and_bad_mask_are_refused():
    model, x0, P0, _ = _linear_data(4)
    f = make_filter("skew-t-kf")
    R = np.array([[1.0, 0.3, 0.0], [0.3, 1.0, 0.0], [0.0, 0.0, 1.0]])
    with pytest.raises(NavlabError, match="diagonal R"):
        f.init(LinearModel(model.F_, model.Q_, model.H_, R), x0, P0)
    object.__setattr__(model, "positive_skew", np.array([True, False]))
    with pytest.raises(NavlabError, match="positive_skew"):
        f.init(model, x0, P0)
    with pytest.raises(NavlabError):
        make_filter("skew-t-kf", {"delta": -1.0})


def test_predictive_logpdf_in_the_kf_limit_is_the_gaussian_innovation_density():
    """δ = 0, ν → ∞: each measurement's predictive density is N(ν_j; 0, S_jj), S = H P⁻ Hᵀ + R."""
    model, x0, P0, z = _linear_data(2, B=3)
    z[1, 4, 0] = np.nan
    f = make_filter("skew-t-kf", {"delta": 0.0, "dof": 1e15, "iters": 2})
    st = f.init(model, x0, P0)
    for k in range(1, z.shape[1]):
        st = f.predict(model, st, k)
        st, out = f.update(model, st, k, z[:, k], side(*z[:, k].shape))
        S = np.diagonal(np.broadcast_to(out.S, (3, model.m, model.m)), axis1=-2, axis2=-1)
        want = stats.norm.logpdf(out.innov, scale=np.sqrt(S))
        ok = np.isfinite(z[:, k])
        np.testing.assert_allclose(out.stats["logpdf"][ok], want[ok], rtol=1e-9)
        assert np.isnan(out.stats["logpdf"][~ok]).all()


def test_nlpd_is_the_mean_negative_logpdf_over_the_window_and_needs_no_truth():
    from navlab.experiment import ExperimentSpec, run_experiment
    from navlab.metrics import summarize

    res = run_experiment(ExperimentSpec(runs=12, epochs=30, filters=("kf", "skew-t-kf"), seed=3))
    df = summarize(res, metrics=["nlpd"])
    lp = res.runs["skew-t-kf"].stats["logpdf"][:, res.data.window]
    got = df[(df["filter"] == "skew-t-kf") & (df.metric == "nlpd")]
    assert got.value.iloc[0] == pytest.approx(-np.nanmean(lp), rel=1e-12)
    assert np.isfinite(got.ci_lo.iloc[0]) and got.ci_lo.iloc[0] < got.value.iloc[0] < got.ci_hi.iloc[0]
    assert df[(df["filter"] == "kf") & (df.metric == "nlpd")].empty  # no stated predictive density
