"""smartloc-berlin pseudorange model: dead reckoning, clock, Jacobians, height aiding, start-up
fix; vb-ekf's missing-channel statistic (satellites come and go). Real-data checks skip without
../shared/data."""

import numpy as np
import pytest

from navlab.data import data_root
from navlab.data.loaders import SMARTLOC_DIR
from navlab.filters.base import make_filter
from navlab.filters.vb_ekf import _fill_missing
from navlab.ins.earth import ecef_to_geodetic, geodetic_to_ecef
from navlab.scenarios.smartloc_berlin import (
    C_LIGHT,
    PrEpochs,
    PseudorangeModel,
    geodetic_up,
    geometric_range,
    robust_ls_fix,
)
from tests.unit.linmodels import side

needs_smartloc = pytest.mark.skipif(
    not (data_root() / SMARTLOC_DIR).is_dir(),
    reason=f"real data not found: {data_root() / SMARTLOC_DIR} (set NAVLAB_DATA)",
)

LAT, LON, HGT = np.radians(52.5), np.radians(13.37), 75.0


def _sky(rng, r0, ms):
    """ms satellites at GNSS-orbit distance above the horizon of r0 (ECEF)."""
    up = r0 / np.linalg.norm(r0)
    dirs = rng.standard_normal((ms, 3))
    dirs += (np.abs(dirs @ up) + 0.3)[:, None] * up  # above the horizon
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    return r0 + 2.2e7 * dirs


def _epochs(K1=6, ms=8, speed=10.0, yaw=0.2, seed=0):
    rng = np.random.default_rng(seed)
    r0 = geodetic_to_ecef(LAT, LON, HGT)
    t = 0.2 * np.arange(K1)
    sat = np.broadcast_to(_sky(rng, r0, ms), (K1, ms, 3)).copy()
    rho = np.linalg.norm(sat - r0, axis=-1)
    sys_idx = np.arange(ms) % 2
    nan = np.full((K1, ms), 40.0)
    ep = PrEpochs(
        t,
        rho,
        sat,
        nan,
        nan,
        nan,
        sys_idx,
        tuple(f"s{j}" for j in range(ms)),
        np.full(K1, speed),
        np.full(K1, yaw),
        np.broadcast_to(r0, (K1, 3)).copy(),
    )
    return ep, r0


def _model(ep, r0, sigma_height=2.0, **kw):
    q = dict(
        sigma_speed=0.05,
        q_heading=1e-4,
        q_pos=0.01,
        q_height=0.05,
        q_clock=0.1,
        q_drift=0.1,
        q_isb=1e-3,
        sigma_norm=0.02,
        sigma_height=sigma_height,
    )
    q.update(kw)
    return PseudorangeModel(ep, np.full(ep.rho.shape, 3.0), r0, **q)


def test_dead_reckoning_follows_the_arc_counter_clockwise():
    # constant speed v and yaw rate ω (CCW +): the heading turns by ωt and the car drives the
    # circle of radius v/ω; the midpoint rule integrates it exactly for constant inputs
    v, w = 10.0, 0.2
    ep, r0 = _epochs(K1=26, speed=v, yaw=w)
    model = _model(ep, r0)
    x = np.zeros((1, 8))
    x[0, 3:5] = [1.0, 0.0]  # heading east
    for k in range(1, 26):
        x = model.f(x, k)
        np.testing.assert_allclose(model.f(x, k), x @ model.F(k).T)  # linear given the odometry
    T = ep.t[-1]
    np.testing.assert_allclose(x[0, 3:5], [np.cos(w * T), np.sin(w * T)], atol=1e-12)
    rad = v / w  # centre of the turn at (0, R): CCW from heading east turns north
    np.testing.assert_allclose(x[0, 0:2], [rad * np.sin(w * T), rad * (1 - np.cos(w * T))], atol=1e-9)


def test_one_oscillator_clock_and_isb_noise():
    ep, r0 = _epochs()
    q_clock, q_isb = 0.3, 2e-3
    Q = _model(ep, r0, q_clock=q_clock, q_isb=q_isb, q_drift=0.0).Q(1)
    T = ep.t[1] - ep.t[0]
    d = np.array([0, 0, 0, 0, 0, -1.0, 1.0, 0])  # c·δt_GLO − c·δt_GPS = ISB
    assert d @ Q @ d == pytest.approx(q_isb * T)
    assert Q[5, 5] == pytest.approx(q_clock * T) and Q[5, 6] == pytest.approx(q_clock * T)
    assert np.all(np.linalg.eigvalsh(_model(ep, r0).Q(1)) >= -1e-15)


def test_jacobian_matches_central_differences():
    ep, r0 = _epochs()
    model = _model(ep, r0)
    x = np.array([[12.0, -7.0, 3.0, 0.6, 0.7, 30.0, 25.0, 1.0]])
    H = model.H(x, 2)[0]
    eps = np.array([1e-3] * 3 + [1e-6] * 2 + [1e-3] * 3)
    J = np.stack(
        [
            (model.h(x + e, 2)[0] - model.h(x - e, 2)[0]) / (2 * e[0, j])
            for j, e in enumerate(np.diag(eps)[:, None, :])
        ],
        axis=1,
    )
    np.testing.assert_allclose(H, J, atol=1e-6 * np.abs(J).max())
    assert model.m == ep.rho.shape[1] + 2  # satellites, ‖d‖, height
    assert _model(ep, r0, sigma_height=None).m == ep.rho.shape[1] + 1


def test_height_channel_is_the_ellipsoidal_height():
    ep, r0 = _epochs()
    model = _model(ep, r0, sigma_height=2.0)
    x = np.zeros((1, 8))
    x[0, 2] = 4.0  # 4 m up
    x[0, 0] = 500.0  # and 500 m east: the plane drops below the ellipsoid by ≈ E²/2R
    h = model.h(x, 1)[0, -1] * 2.0
    assert h == pytest.approx(HGT + 4.0 + 500.0**2 / (2 * 6.39e6), abs=5e-3)
    hh, up = geodetic_up(r0)
    assert hh == pytest.approx(HGT, abs=1e-6)
    np.testing.assert_allclose(up, r0 / np.linalg.norm(r0), atol=4e-3)  # geodetic ≈ geocentric


def test_robust_fix_recovers_position_clocks_and_honours_the_height():
    ep, r0 = _epochs(ms=10)
    clk = np.array([1.5e5, 1.5e5 + 20.0])
    rng_sag, _ = geometric_range(ep.sat[0], r0)
    rho = rng_sag + clk[ep.sys_idx]
    r, c = robust_ls_fix(rho, ep.sat[0], np.full(10, 3.0), ep.sys_idx)
    np.testing.assert_allclose(r, r0, atol=1e-3)
    np.testing.assert_allclose(c, clk, atol=1e-3)
    # one NLOS range (+80 m): Huber keeps the fix within metres; the height prior pins U
    rho[3] += 80.0
    r, _ = robust_ls_fix(rho, ep.sat[0], np.full(10, 3.0), ep.sys_idx, height=HGT, sigma_height=0.1)
    assert np.linalg.norm(r - r0) < 10.0
    assert ecef_to_geodetic(r)[2] == pytest.approx(HGT, abs=0.5)


def test_only_the_pseudoranges_are_positively_skewed():
    """skew-t-kf reads ``positive_skew``: the satellites' channels, not ‖d‖ or the map height."""
    ep, r0 = _epochs()
    model = _model(ep, r0, sigma_height=2.0)
    ms = ep.rho.shape[1]
    assert model.positive_skew.shape == (model.m,) and model.m == ms + 2
    assert model.positive_skew[:ms].all() and not model.positive_skew[ms:].any()


def test_sagnac_is_about_30_m_at_most_at_gnss_ranges():
    ep, r0 = _epochs()
    rng, _ = geometric_range(ep.sat[0], r0)
    geo = np.linalg.norm(ep.sat[0] - r0, axis=-1)
    assert np.all(np.abs(rng - geo) < 7.3e-5 * 2.7e7 * 6.4e6 / C_LIGHT)


def test_vb_statistic_of_missing_channels_is_the_conditional_expectation():
    rng = np.random.default_rng(3)
    B, m = 4, 6
    G = rng.standard_normal((B, m, m))
    R = G @ np.swapaxes(G, -1, -2) + 0.5 * np.eye(m)
    r = rng.standard_normal((B, m))
    BR = r[:, :, None] * r[:, None, :] + 0.1 * np.eye(m)
    ok = rng.random((B, m)) > 0.4
    ok[0] = True
    ok[1, :] = False
    ok[1, 0] = True
    out = _fill_missing(BR, R, ok)
    assert np.all(np.linalg.eigvalsh(out) > -1e-10)  # PSD (the old rule was not)
    np.testing.assert_allclose(out[0], BR[0])  # nothing missing: the plain statistic
    for b in range(B):
        o, mi = np.flatnonzero(ok[b]), np.flatnonzero(~ok[b])
        if not (o.size and mi.size):
            continue
        A = R[b][np.ix_(mi, o)] @ np.linalg.inv(R[b][np.ix_(o, o)])
        Boo = BR[b][np.ix_(o, o)]
        np.testing.assert_allclose(out[b][np.ix_(o, o)], Boo, atol=1e-10)
        np.testing.assert_allclose(out[b][np.ix_(mi, o)], A @ Boo, atol=1e-9)
        np.testing.assert_allclose(
            out[b][np.ix_(mi, mi)], A @ Boo @ A.T + R[b][np.ix_(mi, mi)] - A @ R[b][np.ix_(o, mi)], atol=1e-9
        )


def test_vb_ekf_r_hat_stays_positive_definite_when_channels_come_and_go():
    ep, r0 = _epochs(K1=40, ms=8)
    model = _model(ep, r0)
    rng = np.random.default_rng(5)
    f = make_filter("vb-ekf")
    x0 = np.zeros((2, 8))
    x0[:, 3] = 1.0
    st = f.init(model, x0, np.eye(8))
    x = x0.copy()
    for k in range(1, 40):
        x = model.f(x, k)
        z = model.h(x, k) + rng.standard_normal((2, model.m)) * np.r_[[1.0] * 7, 30.0, 1.0, 1.0]
        z[:, rng.random(model.m) < 0.3] = np.nan  # satellites come and go
        st, out = f.update(model, f.predict(model, st, k), k, z, side(2, model.m))
        R_hat = st.U / (st.u - model.m - 1)
        assert np.linalg.eigvalsh(R_hat).min() > 0
        assert np.all(np.isfinite(out.x))


@needs_smartloc
def test_real_data_every_filter_stays_on_the_road():
    from navlab.experiment import ExperimentSpec, run_experiment

    spec = ExperimentSpec(
        scenario="smartloc-berlin",
        runs=1,
        scenario_params={"epochs": 250},
        filters=("wls", "ekf", "vb-ekf", "chi2-kf"),
    )
    df = run_experiment(spec).metrics()
    med = df[df.metric == "h_err_median"].set_index("filter").value
    assert med.max() < 25.0  # vb-ekf diverged to km, chi2-kf locked out at 345 m before
    assert min(med["ekf"], med["vb-ekf"]) < med["wls"]


def test_map_height_prior_is_a_gauss_markov_process_about_the_map_height():
    ep, r0 = _epochs(K1=400)
    u_ref, sig_h, tau = 4.0, 3.0, 30.0
    model = _model(ep, r0, sigma_height=None, height_prior=(u_ref, sig_h, tau))
    T = ep.t[1] - ep.t[0]
    phi = np.exp(-T / tau)
    assert model.F(1)[2, 2] == pytest.approx(phi)
    assert model.Q(1)[2, 2] == pytest.approx(sig_h**2 * (1 - phi**2))
    # the mean relaxes to U_ref with time constant τ; the stationary variance is σ²
    x = np.zeros((1, 8))
    P = np.zeros((8, 8))
    for k in range(1, 400):
        x = model.f(x, k)
        P = model.F(k) @ P @ model.F(k).T + model.Q(k)
    t = ep.t[-1]
    assert x[0, 2] == pytest.approx(u_ref * (1 - np.exp(-t / tau)), rel=1e-9)
    assert P[2, 2] == pytest.approx(sig_h**2 * (1 - np.exp(-2 * t / tau)), rel=1e-9)
    assert model.m == ep.rho.shape[1] + 1  # no height channel


@needs_smartloc
@pytest.mark.parametrize("mask", ["cn0_mask_dbhz=60", "elevation_mask_deg=80"])
def test_masks_that_leave_no_first_fix_are_refused_in_words(capsys, mask):
    """A C/N0 mask of 60 dBHz was an internal ZeroDivisionError; 80° gave filters at inf m."""
    from navlab.cli import main

    rc = main(
        ["run", "--scenario", "smartloc-berlin", "--runs", "1", "--epochs", "5", "--set", f"scenario.{mask}"]
    )
    err = capsys.readouterr().err
    assert rc == 2 and "pass the masks" in err and "lower scenario." in err
