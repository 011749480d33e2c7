"""15-state NED GPS-RTK/INS with gross errors and a state anomaly (S2 §3; ALGORITHMS.md §8.3).

Simulated replacement of Tan, Wang, Zhao's (S2) vehicle data set (SPAN-CPT + Leica 1200 RTK, 2166 s,
not available): a level drive near Xuzhou (L0 = 34.22°, λ0 = 117.14°, h0 = 40 m) with the speed and
heading profile of §8.3, 1 Hz GPS-RTK position and velocity, the §8.0 error model with Gauss–Markov
sensor biases (τ_g = 100 s, τ_a = 60 s), re-ordered to S2's NED states
``[δp_NED (m), δv_NED (m/s), φ_NED (rad), ε_FRD (rad/s), ∇_FRD (m/s²)]`` and H = [I₆ 0].

The TRUE ERROR STATE is simulated with the same linear model the filters use (§8): x_k = Φ_k x_{k−1}
+ w_k; z_k = [p^INS − p^GPS; v^INS − v^GPS] = H x_k − e_k with e_k the GPS error. Two disturbances
(S2 §3): gross errors on the GPS latitude (+N(3, 0.1²) m) and east velocity (+N(0.3, 0.01²) m/s)
every 20 s from 620 s, and a state anomaly — N(0, 2 (m/s²)²) white noise at 200 Hz on the body-z
specific force over 600–800 s — integrated into the truth's δv_D, δp_D and the IMU Δv_z fed to the
RBF network; the oracle KF is told its equivalent Q block. The noise schedules and outlier models of
navlab apply on top (default: none).

The model also exposes the inputs of NNMFUKF's RBF network (§6.1): ``nn_features(x̂⁺_{k−1}, k)``
(corrected velocity and attitude at k−1, IMU increments over (t_{k−1}, t_k]) and
``nn_reference(k)`` (the INS position/velocity r_k, so that GPS = r_k − z_k).

Note (differs from ALGORITHMS.md §8.3's remark that the network only interpolates): the 600–615 s
right turn at 14 m/s (lateral Δv ≈ +1.47 m/s per second; the training window 200–600 s has at most
+0.79 to the right) and the 14 m/s leg heading south lie outside the training data, and during the
state anomaly the IMU Δv_z input is ≈ 100 training standard deviations away from anything seen in
training; the faithful NNMFUKF is very sensitive to this (see ``nnmfukf-guarded``).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import numpy as np

from navlab.errors import NavlabError
from navlab.filters.base import LinearModel
from navlab.ins.earth import OMEGA_IE_RADPS, normal_gravity, radii
from navlab.ins.strapdown import discretise, error_model_FG
from navlab.linalg import Array
from navlab.noise import OutlierModel, Schedule
from navlab.params import param
from navlab.scenarios.base import (
    MetricGroup,
    Scenario,
    ScenarioData,
    draw_measurement_noise,
    propagate,
    register_scenario,
    run_streams,
)

DEG = np.pi / 180.0
ARCMIN = 60.0 / DEG  # rad -> arcmin
G0 = 9.7803267714
IMU_RATE = 200  # Hz
L0_DEG, LON0_DEG, H0_M = 34.22, 117.14, 40.0

# (t0, t1, forward acceleration m/s², yaw rate °/s) of §8.3 (constant after the last segment)
PROFILE = (
    (0, 60, 0.0, 0.0),
    (60, 80, 0.5, 0.0),
    (80, 140, 0.0, 0.0),
    (140, 150, 0.0, 9.0),
    (150, 200, 0.0, 0.0),
    (200, 220, 0.2, 0.0),
    (220, 260, 0.0, 0.0),
    (260, 275, 0.0, -6.0),
    (275, 330, 0.0, 0.0),
    (330, 350, -0.2, 0.0),
    (350, 380, 0.0, 3.0),
    (380, 440, 0.0, 0.0),
    (440, 460, 0.0, 4.5),
    (460, 520, 0.0, 0.0),
    (520, 540, 0.2, 0.0),
    (540, 560, 0.0, -4.5),
    (560, 600, 0.0, 0.0),
    (600, 615, 0.0, 6.0),
    (615, 660, 0.0, 0.0),
    (660, 680, -0.2, 0.0),
    (680, 700, 0.0, -4.5),
    (700, 740, 0.0, 0.0),
    (740, 760, 0.2, 0.0),
    (760, 775, 0.0, 6.0),
    (775, 800, 0.0, 0.0),
)

STATE_NAMES = (
    "δp_N",
    "δp_E",
    "δp_D",
    "δv_N",
    "δv_E",
    "δv_D",
    "φ_N",
    "φ_E",
    "φ_D",
    "ε_F",
    "ε_R",
    "ε_D",
    "∇_F",
    "∇_R",
    "∇_D",
)
CHANNELS = ("p_N", "p_E", "p_D", "v_N", "v_E", "v_D")
R_STD = np.array([0.1, 0.1, 0.3, 0.04, 0.04, 0.08])


def _signed_perm(pairs: Sequence[tuple[int, int]], n: int) -> Array:
    P = np.zeros((n, n))
    for new, (old, sign) in enumerate(pairs):
        P[new, old] = sign
    return P


# §8.3: §8.0 order [φ ENU, δv ENU, δp NEU, ε RFU, ∇ RFU] -> S2 order [δp NED, δv NED, φ NED, ε FRD, ∇ FRD]
PI_STATE = _signed_perm(
    [
        (6, 1),
        (7, 1),
        (8, -1),
        (4, 1),
        (3, 1),
        (5, -1),
        (1, 1),
        (0, 1),
        (2, -1),
        (10, 1),
        (9, 1),
        (11, -1),
        (13, 1),
        (12, 1),
        (14, -1),
    ],
    15,
)
# noise vector [gyro white, accel white, gyro-bias driving, accel-bias driving], body RFU -> FRD
_PB = [(1, 1), (0, 1), (2, -1)]
PI_NOISE = _signed_perm([(3 * b + o, s) for b in range(4) for (o, s) in _PB], 12)
# NED/ENU and FRD/RFU swap (its own inverse)
SWAP = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def rz(psi: Array) -> Array:
    """C_b^n for a level FRD body in NED with heading ψ (clockwise from north): (…, 3, 3)."""
    c, s = np.cos(psi), np.sin(psi)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


class Trajectory(NamedTuple):
    """The deterministic drive, at the 1 Hz epochs and per interval (k−1, k]."""

    t: Array  # (K+1,)
    pos_ned: Array  # (K+1, 3) m from the start point
    vel_ned: Array  # (K+1, 3)
    yaw: Array  # (K+1,) rad
    lat: Array  # (K+1,) rad
    dtheta: Array  # (K+1, 3) true FRD angle increments over (k−1, k] (row 0 = 0)
    dvel: Array  # (K+1, 3) true FRD velocity increments
    Phi: Array  # (K+1, 15, 15) transition k−1 -> k (row 0 = I)
    Qd: Array  # (K+1, 15, 15)
    Lq: Array  # (K+1, 15, 15) a square root of Qd


@functools.lru_cache(maxsize=4)
def trajectory(
    epochs: int, arw: float, vrw: float, sig_g: float, sig_a: float, tau_g: float, tau_a: float
) -> Trajectory:
    """Simulate the §8.3 drive and the per-epoch error model (cached: identical for every run).

    arw (rad/√s), vrw (m/s/√s), sig_g (rad/s), sig_a (m/s²) are the white-noise and Gauss–Markov
    bias parameters; T = 1 s, IMU at 200 Hz.
    """
    K = int(epochs)
    dt = 1.0 / IMU_RATE
    n_s = K * IMU_RATE
    tm = (np.arange(n_s) + 0.5) * dt  # sample mid-times
    acc = np.zeros(n_s)
    rate = np.zeros(n_s)
    for t0, t1, a, r in PROFILE:
        sel = (tm >= t0) & (tm < t1)
        acc[sel], rate[sel] = a, r * DEG
    sb = np.concatenate([[0.0], np.cumsum(acc * dt)])  # speed at the sample boundaries
    pb = np.concatenate([[0.0], np.cumsum(rate * dt)])  # heading at the boundaries
    s_m, p_m = 0.5 * (sb[1:] + sb[:-1]), 0.5 * (pb[1:] + pb[:-1])
    lat0 = L0_DEG * DEG
    R_Mh0 = radii(lat0, H0_M)[0]
    vN_m, vE_m = s_m * np.cos(p_m), s_m * np.sin(p_m)
    Nb = np.concatenate([[0.0], np.cumsum(vN_m * dt)])
    Eb = np.concatenate([[0.0], np.cumsum(vE_m * dt)])
    lat_m = lat0 + 0.5 * (Nb[1:] + Nb[:-1]) / R_Mh0
    # specific force and angular rate (FRD) at the sample mid-times, §8.3
    R_Mh, R_Nh = radii(lat_m, H0_M)
    v = np.stack([vN_m, vE_m, np.zeros(n_s)], -1)
    vdot = np.stack(
        [
            acc * np.cos(p_m) - s_m * rate * np.sin(p_m),
            acc * np.sin(p_m) + s_m * rate * np.cos(p_m),
            np.zeros(n_s),
        ],
        -1,
    )
    w_ie = OMEGA_IE_RADPS * np.stack([np.cos(lat_m), np.zeros(n_s), -np.sin(lat_m)], -1)
    w_en = np.stack([vE_m / R_Nh, -vN_m / R_Mh, -vE_m * np.tan(lat_m) / R_Nh], -1)
    g = normal_gravity(lat_m, H0_M)
    f_n = vdot + np.cross(2.0 * w_ie + w_en, v) - np.stack([0 * g, 0 * g, g], -1)
    Cnb = np.swapaxes(rz(p_m), -1, -2)
    f_b = (Cnb @ f_n[..., None])[..., 0]
    w_b = (Cnb @ (w_ie + w_en)[..., None])[..., 0] + np.stack([0 * g, 0 * g, rate], -1)
    # per-epoch quantities
    idx = np.arange(K + 1) * IMU_RATE
    t = np.arange(K + 1, dtype=float)
    pos = np.stack([Nb[idx], Eb[idx], np.zeros(K + 1)], -1)
    vel = np.stack([sb[idx] * np.cos(pb[idx]), sb[idx] * np.sin(pb[idx]), np.zeros(K + 1)], -1)
    lat = lat0 + Nb[idx] / R_Mh0
    dth = np.zeros((K + 1, 3))
    dv = np.zeros((K + 1, 3))
    dth[1:] = w_b.reshape(K, IMU_RATE, 3).sum(1) * dt
    dv[1:] = f_b.reshape(K, IMU_RATE, 3).sum(1) * dt
    # error model at the interval midpoints (§8.0 in ENU/RFU, then the signed permutation)
    mid = idx[:-1] + IMU_RATE // 2
    psi_mid = pb[mid]
    v_mid = np.stack([sb[mid] * np.sin(psi_mid), sb[mid] * np.cos(psi_mid), np.zeros(K)], -1)  # ENU
    f_mean = f_n.reshape(K, IMU_RATE, 3).mean(1) @ SWAP.T  # NED -> ENU
    C_bn = SWAP @ rz(psi_mid) @ SWAP  # RFU -> ENU
    F, G = error_model_FG(
        lat0 + Nb[mid] / R_Mh0, np.full(K, H0_M), v_mid, f_mean, C_bn, tau_g_s=tau_g, tau_a_s=tau_a
    )
    F = PI_STATE @ F @ PI_STATE.T
    G = PI_STATE @ G @ PI_NOISE.T
    q_g, q_a = 2.0 * sig_g**2 / tau_g, 2.0 * sig_a**2 / tau_a
    Qc = np.diag([arw**2] * 3 + [vrw**2] * 3 + [q_g] * 3 + [q_a] * 3)
    Phi_k, Qd_k = discretise(F, G, Qc, 1.0)
    Phi = np.concatenate([np.eye(15)[None], Phi_k])
    Qd = np.concatenate([np.zeros((1, 15, 15)), Qd_k])
    w, V = np.linalg.eigh(Qd)
    Lq = V * np.sqrt(np.clip(w, 0.0, None))[:, None, :]
    return Trajectory(t, pos, vel, pb[idx], lat, dth, dv, Phi, Qd, Lq)


@dataclass(frozen=True, eq=False)
class GpsInsModel(LinearModel):
    """The linear error-state model plus the INS/IMU data NNMFUKF's network reads (§6.1).

    ``x_err`` is the INS error (INS − truth) of each run: the INS solution a real system would read
    is nav_true + x_err. Per-run arrays are (B, K+1, …) for the runs of this batch.
    """

    pos_ned: Array | None = None
    vel_ned: Array | None = None
    yaw: Array | None = None
    x_err: Array | None = None
    imu_dv: Array | None = None
    imu_dth: Array | None = None

    def nn_features(self, x_prev: Array, k: int) -> Array:
        """u_k (B, 13) = [v (3), roll, pitch, sin ψ, cos ψ, Δv^b (3), Δθ^b (3)] (§6.1).

        Velocity and attitude are those of the corrected solution at k−1, nav_true + (x_err −
        x̂⁺_{k−1}); the attitude error φ (NED) is taken to the body frame, φ^b = C_n^b φ, and
        (roll, pitch, yaw) = (0, 0, ψ) − φ^b for the level vehicle.
        """
        e = self.x_err[:, k - 1] - x_prev
        v = self.vel_ned[k - 1] + e[:, 3:6]
        psi = self.yaw[k - 1]
        c, s = np.cos(psi), np.sin(psi)
        phb0 = c * e[:, 6] + s * e[:, 7]
        phb1 = -s * e[:, 6] + c * e[:, 7]
        yaw = psi - e[:, 8]
        return np.concatenate(
            [
                v,
                -phb0[:, None],
                -phb1[:, None],
                np.sin(yaw)[:, None],
                np.cos(yaw)[:, None],
                self.imu_dv[:, k],
                self.imu_dth[:, k],
            ],
            axis=1,
        )

    def nn_reference(self, k: int) -> Array:
        """The INS position (NED m from the start) and velocity at k, (B, 6)."""
        return np.concatenate(
            [self.pos_ned[k] + self.x_err[:, k, 0:3], self.vel_ned[k] + self.x_err[:, k, 3:6]],
            axis=1,
        )


@dataclass(frozen=True)
class GpsInsRtkParams:
    epochs: int = param(800, lo=10, hi=20000, help="run length in 1 s epochs (S2 analysis ends at 800 s)")
    gross_errors: bool = param(True, help="GPS gross errors on latitude and east velocity (S2 §3)")
    gross_start: int = param(620, lo=1, hi=10**6, help="first gross-error epoch (s)")
    gross_stop: int = param(780, lo=1, hi=10**6, help="last gross-error epoch (s)")
    gross_every: int = param(20, lo=1, hi=10**6, help="gross-error period (s)")
    gross_vel_offset: int = param(0, lo=0, hi=10**6, help="delay of the velocity gross errors (s)")
    gross_lat_m: float = param(3.0, lo=-1000.0, hi=1000.0, help="latitude gross-error mean (m)")
    gross_lat_std_m: float = param(0.1, lo=0.0, hi=100.0, help="latitude gross-error std (m)")
    gross_ve_mps: float = param(0.3, lo=-100.0, hi=100.0, help="east-velocity gross-error mean (m/s)")
    gross_ve_std_mps: float = param(0.01, lo=0.0, hi=10.0, help="east-velocity gross-error std (m/s)")
    state_anomaly: bool = param(True, help="white noise on the body-z specific force (S2 §3)")
    anomaly_start: int = param(600, lo=0, hi=10**6, help="state anomaly from (s)")
    anomaly_stop: int = param(800, lo=0, hi=10**6, help="state anomaly until (s)")
    anomaly_var: float = param(
        2.0,
        lo=0.0,
        hi=1000.0,
        help="variance of the 200 Hz specific-force noise ((m/s²)²; S2's N(0,2); 4 = the std reading)",
    )
    window_start: int = param(600, lo=0, hi=10**6, help="analysis window start (s)")
    window_stop: int = param(800, lo=0, hi=10**6, help="analysis window end (s)")
    arw_deg_rth: float = param(0.07, lo=0.0, hi=100.0, help="gyro angle random walk (°/√h)")
    vrw_mps_rth: float = param(0.05, lo=0.0, hi=100.0, help="accelerometer velocity random walk (m/s/√h)")
    gyro_bias_dph: float = param(5.0, lo=0.0, hi=1000.0, help="gyro bias σ (°/h), Gauss–Markov")
    accel_bias_ug: float = param(50.0, lo=0.0, hi=1e5, help="accelerometer bias σ (µg), Gauss–Markov")
    tau_g_s: float = param(100.0, lo=1.0, hi=1e6, help="gyro bias correlation time (s)")
    tau_a_s: float = param(60.0, lo=1.0, hi=1e6, help="accelerometer bias correlation time (s)")


def _state_anomaly(p: GpsInsRtkParams, t: Array, streams, B: int) -> tuple[Array, Array, Array]:
    """The anomaly's epochs and its δv_D, δp_D per run and epoch: (epochs (K+1,), dv, dp (B, K+1)).

    The anomaly (§8.3): N(0, anomaly_var) white noise n_i on the body-z specific force at 200 Hz
    over each anomaly second, integrated into δv_D and δp_D: Δv = T Σ n_i,
    Δp = T Σ n_i (1 − t_i + T/2). Both are linear in the n_i, so they are drawn exactly as the
    2-D Gaussian with the covariance of those sums (the same distribution as summing 200 draws,
    100× fewer draws).
    """
    dt = 1.0 / IMU_RATE
    anom_ep = (t > p.anomaly_start) & (t <= p.anomaly_stop) & p.state_anomaly & (t > 0)
    n_an = int(anom_ep.sum())
    ti = np.arange(1, IMU_RATE + 1) * dt
    dv_an = np.zeros((B, len(t)))
    dp_an = np.zeros((B, len(t)))
    if n_an:
        A = dt * np.stack([np.ones(IMU_RATE), 1.0 - ti + dt / 2])  # [Δv; Δp] = A n
        L_an = np.linalg.cholesky(p.anomaly_var * A @ A.T)
        dvp = streams.aux.standard_normal((n_an, 2)) @ L_an.T
        dv_an[:, anom_ep], dp_an[:, anom_ep] = dvp[..., 0], dvp[..., 1]
    return anom_ep, dv_an, dp_an


def _anomaly_Q(anomaly_var: float, anom_ep: Array) -> Array:
    """(K+1, 15, 15) the anomaly's process noise on δp_D, δv_D over its epochs (for the oracle)."""
    q = anomaly_var * (1.0 / IMU_RATE)
    Q_extra = np.zeros((len(anom_ep), 15, 15))
    Q_extra[np.ix_(anom_ep, [2, 5], [2, 5])] = q * np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]])
    return Q_extra


def _true_errors(tr: Trajectory, p0_std: Array, streams, dv_an: Array, dp_an: Array) -> Array:
    """(B, K+1, 15) the true error state: x_k = Φ_k x_{k−1} + w_k, the anomaly added at its epochs."""
    K = len(tr.t) - 1
    x0_true = streams.truth.standard_normal(15) * p0_std
    wn = streams.truth.standard_normal((K, 15))
    anomaly = np.zeros((dv_an.shape[0], K, 15))  # added to δp_D, δv_D at its epoch, then propagated by Φ
    anomaly[..., 2], anomaly[..., 5] = dp_an[:, 1:], dv_an[:, 1:]
    return propagate(x0_true, tr.Phi, wn, tr.Lq, anomaly)


def _imu_increments(
    tr: Trajectory, x: Array, streams, arw: float, vrw: float, dv_an: Array
) -> tuple[Array, Array]:
    """IMU increments with the truth's sensor errors, white noise and the anomaly (NN inputs): (Δθ, Δv)."""
    B, K1 = x.shape[:2]
    imu_n = streams.aux.standard_normal((K1, 6))
    imu_dth = (
        tr.dtheta + np.concatenate([np.zeros((B, 1, 3)), x[:, :-1, 9:12]], axis=1) + arw * imu_n[..., :3]
    )
    imu_dv = tr.dvel + np.concatenate([np.zeros((B, 1, 3)), x[:, :-1, 12:15]], axis=1)
    imu_dv = imu_dv + vrw * imu_n[..., 3:]
    imu_dv[:, :, 2] += dv_an
    imu_dth[:, 0] = 0.0
    imu_dv[:, 0] = 0.0
    return imu_dth, imu_dv


def _gross_errors(p: GpsInsRtkParams, streams, B: int, K: int) -> tuple[Array, Array, Array, Array]:
    """S2's gross errors on latitude and east velocity: (errors, variances, mask, means), (B, K+1, 6)."""
    gross = np.zeros((B, K + 1, 6))
    gvar = np.zeros((B, K + 1, 6))
    gmask = np.zeros((B, K + 1, 6), dtype=bool)
    gmean = np.zeros((B, K + 1, 6))
    if p.gross_errors:
        ep_lat = np.arange(p.gross_start, min(p.gross_stop, K) + 1, p.gross_every)
        ep_ve = ep_lat + p.gross_vel_offset
        ep_ve = ep_ve[ep_ve <= K]
        gn = streams.aux.standard_normal((2, K + 1))
        for ch, eps, mu, sd, row in (
            (0, ep_lat, p.gross_lat_m, p.gross_lat_std_m, 0),
            (4, ep_ve, p.gross_ve_mps, p.gross_ve_std_mps, 1),
        ):
            gross[:, eps, ch] = mu + sd * gn[:, row, eps]
            gvar[:, eps, ch] = sd**2
            gmean[:, eps, ch] = mu
            gmask[:, eps, ch] = True
    return gross, gvar, gmask, gmean


def _rtk_groups() -> dict[str, MetricGroup]:
    """Position, velocity, attitude (arcmin) and each of their axes."""
    return {
        "pos": MetricGroup((0, 1, 2), "m", "position"),
        "vel": MetricGroup((3, 4, 5), "m/s", "velocity"),
        "att": MetricGroup((6, 7, 8), "arcmin", "attitude (φ_N, φ_E, φ_D)", ARCMIN),
        "pos_N": MetricGroup((0,), "m", "north (latitude) position"),
        "pos_E": MetricGroup((1,), "m", "east position"),
        "pos_D": MetricGroup((2,), "m", "down position"),
        "vel_N": MetricGroup((3,), "m/s", "north velocity"),
        "vel_E": MetricGroup((4,), "m/s", "east velocity"),
        "vel_D": MetricGroup((5,), "m/s", "down velocity"),
        "heading": MetricGroup((8,), "arcmin", "heading (φ_D)", ARCMIN),
    }


@register_scenario
class GpsInsRtk(Scenario):
    key = "gps-ins-rtk"
    label = "GPS-RTK/INS, gross errors + state anomaly (15-state NED)"
    paper = "Tan, Wang, Zhao 2015 (NNMFUKF), §3"
    summary = (
        "A car drives 800 s with 1 Hz RTK position/velocity aiding a navigation-grade INS; from 600 s "
        "the vertical specific force is disturbed (state anomaly) and every 20 s the GPS latitude and "
        "east velocity carry gross errors."
    )
    Params = GpsInsRtkParams
    outlier_defaults: ClassVar[dict[str, dict[str, Any]]] = {
        "mixture": {"contamination": 0.0},
        "isolated": {"start": 620, "stop": 780, "every": 20, "mean": 30.0, "scale": 1.0, "channels": [0]},
        "continuous": {"start": 700, "stop": 720, "mean": 0.0, "scale": 10.0, "channels": [0]},
    }
    default_filters = ("svd-ukf", "mfukf", "nnmfukf", "nnmfukf-guarded", "oracle-kf")
    default_runs = 20
    headline = ("pos", "vel", "att")

    def _check(self) -> None:
        p = self.params
        if p.window_stop < p.window_start:
            raise NavlabError("gps-ins-rtk: window_stop must not be before window_start")
        if p.anomaly_stop < p.anomaly_start:
            raise NavlabError("gps-ins-rtk: anomaly_stop must not be before anomaly_start")
        if p.gross_stop < p.gross_start:
            raise NavlabError("gps-ins-rtk: gross_stop must not be before gross_start")

    def simulate(
        self, schedule: Schedule, outliers: OutlierModel, runs: Sequence[int], seed: int
    ) -> ScenarioData:
        p = self.params
        self._check()
        K = p.epochs
        arw = p.arw_deg_rth * DEG / 60.0
        vrw = p.vrw_mps_rth / 60.0
        sig_g = p.gyro_bias_dph * DEG / 3600.0
        sig_a = p.accel_bias_ug * 1e-6 * G0
        tr = trajectory(K, arw, vrw, sig_g, sig_a, p.tau_g_s, p.tau_a_s)
        p0_std = np.array(
            [1.0, 1.0, 2.0] + [0.5] * 3 + [1 * DEG, 1 * DEG, 3 * DEG] + [sig_g] * 3 + [sig_a] * 3
        )
        H = np.hstack([np.eye(6), np.zeros((6, 9))])
        streams = run_streams(seed, runs)
        B = len(streams)
        t = tr.t
        anom_ep, dv_an, dp_an = _state_anomaly(p, t, streams, B)
        x = _true_errors(tr, p0_std, streams, dv_an, dp_an)
        imu_dth, imu_dv = _imu_increments(tr, x, streams, arw, vrw, dv_an)
        # GPS errors: schedule/outlier model, then S2's gross errors; z = H x − e
        std = schedule.std(R_STD, K)
        noise, var, bias, mask = draw_measurement_noise(streams, std, outliers)
        gross, gvar, gmask, gmean = _gross_errors(p, streams, B, K)
        z = np.einsum("ij,bkj->bki", H, x) - (noise + gross)
        z[:, 0] = np.nan
        window = (t >= p.window_start) & (t <= p.window_stop) & (t > 0)
        if not window.any():
            window = t > 0
        model = GpsInsModel(
            tr.Phi,
            tr.Qd,
            H,
            np.diag(R_STD**2),
            pos_ned=tr.pos_ned,
            vel_ned=tr.vel_ned,
            yaw=tr.yaw,
            x_err=x,
            imu_dv=imu_dv,
            imu_dth=imu_dth,
        )
        return ScenarioData(
            scenario=self.key,
            t=t,
            model=model,
            x_true=x,
            z=z,
            R_true=var + gvar,
            R_schedule=std**2,
            outlier_mask=mask | gmask,
            bias=-(bias + gmean),
            x0=np.zeros((B, 15)),
            P0=np.diag(p0_std**2),
            runs=np.asarray(runs),
            state_names=STATE_NAMES,
            channel_names=CHANNELS,
            channel_units=("m", "m", "m", "m/s", "m/s", "m/s"),
            groups=_rtk_groups(),
            window=window,
            Q_extra=_anomaly_Q(p.anomaly_var, anom_ep),
            extras={"gross_mask": gmask, "anomaly_epochs": anom_ep},
        )
