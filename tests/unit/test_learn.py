"""The Learn page's step-through (navlab/learn.py): hand-computed KF, outlier NIS, every filter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from navlab.errors import NavlabError
from navlab.filters import registry
from navlab.learn import (
    STEP_COLUMNS,
    TinySpec,
    applicability,
    equations,
    filter_info,
    simulate_tiny,
    step_through,
)


def _hand_kf(data):
    """A KF written out by hand (short-form covariance, explicit inverse): x, P, ν, S per epoch."""
    F, Q, H, R = data.model.F_, data.model.Q_, data.model.H_, data.model.R0
    x, P = data.x0.copy(), data.P0.copy()
    out = []
    for k in range(1, data.K + 1):
        x = F @ x
        P = F @ P @ F.T + Q
        nu = data.z[k] - H @ x
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        x = x + K @ nu
        P = (np.eye(len(x)) - K @ H) @ P
        out.append((x.copy(), P.copy(), nu, S))
    return out


@pytest.mark.parametrize("dims", [1, 2])
def test_kf_step_through_matches_hand_computed_update(dims):
    spec = TinySpec(dims=dims, epochs=6, outlier_epoch=3, outlier_size=5.0, seed=3)
    res = step_through("kf", spec)
    assert res.applicable, res.reason
    hand = _hand_kf(res.data)
    for k, (x, P, nu, S) in enumerate(hand, start=1):
        rows = res.steps[res.steps.epoch == k]
        np.testing.assert_allclose(rows["innov"].to_numpy(), nu, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(rows["S"].to_numpy(), np.diag(S), rtol=1e-10)
        nis = float(nu @ np.linalg.solve(S, nu))
        np.testing.assert_allclose(rows["nis"].to_numpy(), nis, rtol=1e-9)
        st = res.states[res.states.epoch == k]
        np.testing.assert_allclose(st["posterior"].to_numpy(), x, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(st["P_post"].to_numpy(), np.diag(P), rtol=1e-9)
        np.testing.assert_allclose(rows["z_pred"].to_numpy() + rows["innov"].to_numpy(), rows["z"].to_numpy())


def test_first_kf_update_by_hand_1d():
    """One update written with scalars: x⁻ = [p+v, v], S = P⁻₁₁ + r, K = P⁻[:,0]/S."""
    spec = TinySpec(dims=1, epochs=1, outlier_epoch=0, q=0.0, r=2.0, p0_pos=4.0, p0_vel=1.0)
    res = step_through("kf", spec)
    d = res.data
    p, v = d.x0
    # F = [[1, 1], [0, 1]], Q = 0: P⁻ = [[4 + 1, 1], [1, 1]]
    P11, P12 = 5.0, 1.0
    S = P11 + 2.0
    nu = d.z[1, 0] - (p + v)
    post = res.states[res.states.epoch == 1]["posterior"].to_numpy()
    np.testing.assert_allclose(post, [p + v + P11 / S * nu, v + P12 / S * nu], rtol=1e-12)
    np.testing.assert_allclose(res.steps["S"].iloc[0], S)
    np.testing.assert_allclose(res.steps["nis"].iloc[0], nu**2 / S)


@pytest.mark.parametrize("dims", [1, 2])
@pytest.mark.parametrize("j", [2, 5])
def test_outlier_at_epoch_j_exceeds_the_chi2_threshold_there(dims, j):
    spec = TinySpec(dims=dims, epochs=7, outlier_epoch=j, outlier_size=12.0, seed=1, alpha=0.01)
    res = step_through("kf", spec)
    ep = res.epoch_table().set_index("epoch")
    thr = chi2.ppf(0.99, dims)
    assert math.isclose(res.threshold, thr)
    assert ep.loc[j, "nis"] > thr
    assert bool(ep.loc[j, "nis_exceeds"])
    assert bool(ep.loc[j, "outlier"])
    # causality: before epoch j everything equals the outlier-free run; at j the NIS jumps
    clean = step_through("kf", TinySpec(dims=dims, epochs=7, outlier_epoch=0, seed=1))
    cl = clean.epoch_table().set_index("epoch")
    np.testing.assert_allclose(ep.loc[: j - 1, "nis"], cl.loc[: j - 1, "nis"], rtol=1e-12)
    assert ep.loc[j, "nis"] > cl.loc[j, "nis"] + 20


def test_no_outlier_means_no_outlier_rows():
    res = step_through("kf", TinySpec(outlier_epoch=0))
    assert not res.steps["outlier"].any()
    data = simulate_tiny(TinySpec(outlier_epoch=0))
    assert not data.bias.any()


def test_outlier_on_all_channels():
    data = simulate_tiny(TinySpec(dims=2, outlier_epoch=4, outlier_channel="all"))
    assert data.outlier[4].all() and data.outlier.sum() == 2
    np.testing.assert_allclose(data.bias[4], 10.0)


def test_chi2_kf_rejects_the_outlier_epoch():
    res = step_through("chi2-kf", TinySpec(outlier_epoch=4, outlier_size=15.0))
    rows = res.steps[res.steps.epoch == 4]
    assert (rows["flag_name"] == "rejected").all()
    assert (rows["weight"] == 0).all()
    st = res.states[res.states.epoch == 4]
    np.testing.assert_allclose(st["posterior"], st["prior"])


@pytest.mark.parametrize("key", sorted(registry()))
def test_every_registered_filter_runs_or_is_reported_not_applicable(key):
    res = step_through(key, TinySpec(dims=2, epochs=6, outlier_epoch=3))
    if res.applicable:
        assert len(res.steps) == 6 * 2
        assert set(STEP_COLUMNS) <= set(res.steps.columns)
        assert np.isfinite(res.states["posterior"].to_numpy(dtype=float)).all()
        assert np.isfinite(res.steps["nis"].to_numpy(dtype=float)).all()
    else:
        assert res.reason  # says why
        assert res.steps.empty


def test_applicability_covers_the_registry():
    out = applicability(TinySpec(epochs=3, outlier_epoch=2))
    assert set(out) == set(registry())
    assert out["kf"].applicable


def test_a_failing_filter_is_not_applicable_not_an_exception(monkeypatch):
    from navlab.filters import kalman

    def boom(self, model, state, k, z, side):
        raise KeyError("needs INS increments")

    monkeypatch.setattr(kalman.KF, "update", boom)
    res = step_through("kf", TinySpec(epochs=2, outlier_epoch=1))
    assert not res.applicable
    assert "KeyError" in res.reason


@pytest.mark.parametrize(
    "bad",
    [
        {"dims": 3},
        {"epochs": 0},
        {"outlier_epoch": 99},
        {"r": 0.0},
        {"alpha": 0.9},
        {"outlier_channel": "second"},
        {"q": float("nan")},
    ],
)
def test_bad_spec_is_a_navlab_error(bad):
    with pytest.raises(NavlabError):
        step_through("kf", TinySpec(**bad))


def test_unknown_filter_and_bad_params_are_navlab_errors():
    with pytest.raises(NavlabError, match="unknown filter"):
        step_through("no-such-filter")
    with pytest.raises(NavlabError):
        step_through("chi2-kf", params={"alpha": 2.0})


def test_equations_and_ideas():
    for key in (
        "kf",
        "oracle-kf",
        "chi2-kf",
        "huber-kf",
        "vb-akf",
        "hakf",
        "student-t-kf",
        "sage-husa",
        "irakf",
        "rrae",
        "rakf",
        "rsshakf",
        "ekf",
        "svd-ukf",
        "mfukf",
        "nnmfukf",
        "vb-ekf",
        "wls",
    ):
        assert equations(key), key
        assert registry()[key].teaching.idea, key
    assert equations("unknown-key") == []
    assert equations("nnmfukf-guarded") == equations("nnmfukf")  # a variant: its base's
    assert equations("kfx") == []  # not a "<base>-" variant
    assert all(isinstance(s, str) and s for c in registry().values() for s in c.teaching.equations)
    info = filter_info(registry()["chi2-kf"])
    assert info["equations"] and info["idea"] and info["params"]


def test_nominal_nis_equals_own_nis_for_the_kf():
    res = step_through("kf", TinySpec(dims=2, outlier_epoch=3))
    np.testing.assert_allclose(res.steps["nis_nominal"], res.steps["nis"], rtol=1e-10)


@pytest.mark.parametrize("key", ["huber-kf", "chi2-kf", "student-t-kf"])
def test_robust_filters_own_nis_hides_what_the_nominal_nis_shows(key):
    """Whatever the filter does with it, a 15σ outlier exceeds χ² against the nominal S₀."""
    if key not in registry():
        pytest.skip(f"{key} not registered")
    res = step_through(key, TinySpec(dims=2, epochs=6, outlier_epoch=4, outlier_size=15.0))
    ep = res.epoch_table().set_index("epoch")
    assert ep.loc[4, "nis_nominal"] > res.threshold
