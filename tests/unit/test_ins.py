"""Strapdown INS: closed-form checks, the error model against finite differences, alignment."""

import numpy as np
import pytest
from scipy.linalg import expm

from navlab.errors import NavlabError
from navlab.ins import (
    align_static,
    apply_correction,
    discretise,
    error_model_FG,
    init_state,
    propagate_block,
)
from navlab.ins.earth import (
    OMEGA_IE_RADPS,
    dcm_to_euler,
    dcm_to_rotvec,
    earth_rate_enu,
    euler_to_dcm,
    normal_gravity,
    radii,
    transport_rate_enu,
)

LAT, LON, H = np.radians(40.1), np.radians(-105.15), 1600.0
DT = 0.01


def _stationary_imu(C_bn, lat=LAT, h=H):
    """Exact body specific force and rate of a vehicle at rest (gravity and Earth rate only)."""
    g = float(normal_gravity(lat, h))
    f_b = C_bn.T @ np.array([0.0, 0.0, g])
    w_b = C_bn.T @ earth_rate_enu(lat)
    return f_b, w_b


def _run(state, f_b, w_b, T, dt=DT):
    N = round(T / dt)
    t = state.t_s + dt * np.arange(N)
    return propagate_block(state, t, np.tile(f_b, (N, 1)), np.tile(w_b, (N, 1)), t_end_s=state.t_s + T)[0]


def _pos_err_m(s, lat, lon, h):
    R_Mh, R_Nh = radii(lat, h)
    return np.stack([(s.lat_rad - lat) * R_Mh, (s.lon_rad - lon) * R_Nh * np.cos(lat), s.h_m - h], -1)


def test_stationary_stays_put():
    C = euler_to_dcm(np.radians(2.0), np.radians(-3.0), np.radians(130.0))
    f_b, w_b = _stationary_imu(C)
    s0 = init_state(LAT, LON, H, np.zeros(3), C)
    s = _run(s0, f_b, w_b, 300.0, dt=0.1)
    # exact inputs: only the integration error remains (first-order Earth-rate attitude update)
    assert np.abs(_pos_err_m(s, LAT, LON, H)).max() < 0.05
    assert np.abs(s.v_enu_mps).max() < 1e-3
    assert np.degrees(np.abs(dcm_to_rotvec(s.C_bn @ C.T)).max()) < 1e-4


def test_stationary_accel_bias_closed_form():
    """An east accelerometer bias b: position error ½ b t² (Schuler-corrected) with error = INS − truth."""
    C = np.eye(3)
    f_b, w_b = _stationary_imu(C)
    b = 0.01
    T = 60.0
    s = _run(init_state(LAT, LON, H, np.zeros(3), C), f_b + np.array([b, 0, 0]), w_b, T, dt=0.05)
    e = _pos_err_m(s, LAT, LON, H)[0]
    ws2 = float(normal_gravity(LAT, H)) / 6.371e6  # Schuler ω_s²: δp = b/ω_s² (1 − cos ω_s t)
    expected = b / ws2 * (1 - np.cos(np.sqrt(ws2) * T))
    assert e[1] == pytest.approx(expected, rel=0.02)  # east
    assert abs(e[0]) < 0.05 * expected  # north: only Coriolis cross-coupling


def test_stationary_gyro_bias_closed_form():
    """A north-axis gyro bias ε tilts the platform: east velocity error ≈ −g ε t²/2."""
    C = np.eye(3)
    f_b, w_b = _stationary_imu(C)
    eps = np.radians(0.01)  # 36 deg/h
    T = 30.0
    s = _run(init_state(LAT, LON, H, np.zeros(3), C), f_b, w_b + np.array([0, eps, 0]), T, dt=0.05)
    g = float(normal_gravity(LAT, H))
    dvE = s.v_enu_mps[0, 0]
    assert abs(dvE) == pytest.approx(g * eps * T**2 / 2, rel=0.03)
    # consistent with the error model: φ̇ = −C ε, δv̇ = f^n × φ; f^n = (0,0,g), φ_N = −ε t
    # → δv̇_E = f_N φ_U − f_U φ_N = g ε t → δv_E = +g ε t²/2
    assert dvE > 0


def test_constant_velocity_meridian():
    """Level car driving north at 10 m/s: the exact inputs keep the speed and follow the meridian."""
    v = np.array([0.0, 10.0, 0.0])
    C = np.eye(3)
    g = float(normal_gravity(LAT, H))
    w_ie = earth_rate_enu(LAT)
    w_en = transport_rate_enu(LAT, H, v)
    f_n = np.cross(2 * w_ie + w_en, v) + np.array([0, 0, g])
    w_b = C.T @ (w_ie + w_en)
    s = _run(init_state(LAT, LON, H, v, C), C.T @ f_n, w_b, 60.0, dt=0.05)
    R_Mh, _ = radii(LAT, H)
    dn = (s.lat_rad[0] - LAT) * R_Mh
    assert dn == pytest.approx(600.0, abs=0.05)
    assert abs(s.lon_rad[0] - LON) * 6.4e6 < 0.05
    assert abs(s.h_m[0] - H) < 0.05
    assert np.abs(s.v_enu_mps[0] - v).max() < 5e-3


def _error(ins, truth):
    """Error state INS − truth in the §8.0 order (φ from C_ins = (I − [φ×]) C_true)."""
    phi = -dcm_to_rotvec(ins.C_bn @ np.swapaxes(truth.C_bn, -1, -2))
    dv = ins.v_enu_mps - truth.v_enu_mps
    R_Mh, R_Nh = radii(truth.lat_rad, truth.h_m)
    dp = np.stack(
        [
            (ins.lat_rad - truth.lat_rad) * R_Mh,
            (ins.lon_rad - truth.lon_rad) * R_Nh * np.cos(truth.lat_rad),
            ins.h_m - truth.h_m,
        ],
        -1,
    )
    return np.concatenate(
        [phi, dv, dp, truth.bias_g_radps - ins.bias_g_radps, truth.bias_a_mps2 - ins.bias_a_mps2], axis=-1
    )


def test_error_model_matches_finite_differences():
    """Φ = expm(F T) equals the Jacobian of the mechanisation's error propagation (error = INS − truth)."""
    v = np.array([12.0, -7.0, 0.3])
    C = euler_to_dcm(np.radians(4.0), np.radians(-6.0), np.radians(210.0))
    g = float(normal_gravity(LAT, H))
    w_ie, w_en = earth_rate_enu(LAT), transport_rate_enu(LAT, H, v)
    f_n = np.cross(2 * w_ie + w_en, v) + np.array([0.5, -0.3, g + 0.2])  # plus a manoeuvre
    f_b, w_b = C.T @ f_n, C.T @ (w_ie + w_en) + np.array([0.0, 0.0, 0.02])
    truth = init_state(LAT, LON, H, v, C)
    scales = np.r_[[1e-4] * 3, [1e-2] * 3, [1.0] * 3, [1e-5] * 3, [1e-3] * 3]
    n = 15
    dX = np.concatenate([np.diag(scales), -np.diag(scales)])  # ± perturbation of each state
    B = 2 * n
    tb = init_state(np.full(B, LAT), LON, H, v, np.broadcast_to(C, (B, 3, 3)))
    ins0 = apply_correction(tb, -dX)  # INS = truth with error dX
    np.testing.assert_allclose(_error(ins0, tb), dX, rtol=1e-6, atol=1e-12)
    T = 1.0
    ins1 = _run(ins0, f_b, w_b, T)
    tr1 = _run(truth, f_b, w_b, T)
    trB = init_state(
        np.full(B, tr1.lat_rad[0]),
        tr1.lon_rad[0],
        tr1.h_m[0],
        tr1.v_enu_mps[0],
        np.broadcast_to(tr1.C_bn[0], (B, 3, 3)),
    )
    e1 = _error(ins1, trB)
    J = (e1[:n] - e1[n:]).T / (2 * scales[None, :])
    # the mechanisation's gravity depends on h: compare with the gravity-gradient option on
    F, _ = error_model_FG(LAT, H, v, f_n, C, gravity_gradient=True)
    Phi = expm(F[0] * T)
    # compare column by column in the perturbation's scale, relative to the column's size
    for j in range(n):
        col = (J[:, j] - Phi[:, j]) * scales[j] / scales
        ref = np.maximum(np.abs(Phi[:, j] * scales[j] / scales), 1e-3)
        assert np.all(np.abs(col) <= 0.03 * ref + 2e-4), (j, J[:, j], Phi[:, j])


def test_discretise_matches_expm_for_small_step():
    F, G = error_model_FG(
        LAT, H, np.array([5.0, 3.0, 0.0]), np.array([0.3, 0.1, 9.8]), euler_to_dcm(0.0, 0.0, 1.0)
    )
    Qc = np.diag([1e-6] * 3 + [1e-4] * 3 + [1e-10] * 3 + [1e-8] * 3)
    Phi, Qd = discretise(F, G, Qc, 0.01)
    np.testing.assert_allclose(Phi[0], expm(F[0] * 0.01), atol=5e-6)  # O((FT)³/6)
    assert np.all(np.linalg.eigvalsh(Qd[0]) > -1e-18)


def test_alignment_recovers_attitude_and_gyro_bias():
    rng = np.random.default_rng(3)
    pitch, roll, heading = np.radians([3.0, -2.0, 130.0])
    C = euler_to_dcm(pitch, roll, heading)
    f_b, w_b = _stationary_imu(C)
    bias = np.radians([0.1, -0.05, 0.2])
    N = 3000
    f = f_b + 0.05 * rng.standard_normal((N, 3))
    w = w_b + bias + 1e-3 * rng.standard_normal((N, 3))
    res = align_static(f, w, LAT, H, heading)
    assert res.pitch_deg == pytest.approx(3.0, abs=0.01)
    assert res.roll_deg == pytest.approx(-2.0, abs=0.01)
    assert res.heading_deg % 360 == pytest.approx(130.0, abs=1e-6)
    np.testing.assert_allclose(res.gyro_bias_radps, bias, atol=1e-4)
    np.testing.assert_allclose(
        np.degrees(dcm_to_euler(res.C_bn)), np.degrees([pitch, roll, heading]), atol=0.01
    )
    assert OMEGA_IE_RADPS > 0


def test_alignment_rejects_wrong_units():
    f = np.tile([0.0, 0.0, 1.0], (100, 1))  # in g, not m/s²
    with pytest.raises(NavlabError, match="m/s"):
        align_static(f, np.zeros((100, 3)), LAT, H, 0.0)
