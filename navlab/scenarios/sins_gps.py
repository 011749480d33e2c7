"""SINS/GPS position-aided attitude estimation of the HAKF paper (Zuo et al. 2017, §2; ALGORITHMS.md §8.1).

The 15-state SINS error model of §8.0 (``navlab.ins.strapdown.error_model_FG`` and its
second-order discretisation ``discretise``) is simulated as a LINEAR model (the general pattern
at the top of §8): x^true_k = Φ_k x^true_{k−1} + w_k, x^true_0 ~ N(0, P0), z_k = δp_k + v_k
(GPS position minus INS position, metres N, E, U). Every filter starts at x̂_0 = 0 with P0 and
assumes R = diag(10 m)² on N, E, U.

The four noise cases of the paper (scenario parameter ``case``):

1. Gaussian, σ = 10 m;
2. time-varying σ by eqs. 29–31 (the ``hakf-tanh`` schedule; r' read as a standard deviation);
3. Gaussian-mixture outliers by eq. 32 (the ``mixture`` outlier model, α_c = 0.1, κ_o = 10 by
   default — the paper gives neither);
4. cases 2 and 3 together.

``case = 0`` uses the experiment's own noise schedule and outlier model instead.

Defaults the paper does not give (§8.1, §10 #1–5): T = 1 s, L0 = 34°, h0 = 380 m, a level
``turning`` trajectory (10 m/s, 0.02 rad/s), navigation-grade IMU (ARW 0.01 °/√h, VRW 10 µg/√Hz,
bias random walks 0.001 (°/h)/√s and 1 µg/√s), P0 = diag(0.1°, 0.1°, 0.5°, 0.1 m/s, 10 m,
0.1 °/h, 100 µg)².
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from navlab.filters.base import LinearModel
from navlab.ins.earth import normal_gravity
from navlab.ins.strapdown import discretise, error_model_FG
from navlab.linalg import Array
from navlab.noise import OutlierModel, Schedule, make_outliers, make_schedule
from navlab.noise.outliers import Mixture
from navlab.params import MAX_EPOCHS, param
from navlab.scenarios.base import (
    MetricGroup,
    Scenario,
    ScenarioData,
    draw_measurement_noise,
    propagate,
    register_scenario,
    run_streams,
)

__all__ = ["ARCMIN", "SinsGps", "SinsGpsParams", "body_attitude_errors", "sins_gps_model"]

G0 = 9.7803267714  # PSINS glv.g0, for µg
DEG = np.pi / 180.0
ARCMIN = 180.0 / np.pi * 60.0  # rad -> arcmin
DPH = DEG / 3600.0  # °/h -> rad/s
UG = 1e-6 * G0  # µg -> m/s²

STATE_NAMES = (
    "phi_E",
    "phi_N",
    "phi_U",
    "dv_E",
    "dv_N",
    "dv_U",
    "dp_N",
    "dp_E",
    "dp_U",
    "eps_x",
    "eps_y",
    "eps_z",
    "nabla_x",
    "nabla_y",
    "nabla_z",
)

CASES = {
    1: ("constant", "none"),
    2: ("hakf-tanh", "none"),
    3: ("constant", "mixture"),
    4: ("hakf-tanh", "mixture"),
}


@dataclass(frozen=True)
class SinsGpsParams:
    epochs: int = param(850, lo=2, hi=MAX_EPOCHS, help="number of GPS epochs (paper: len = 850)")
    case: int = param(
        0,
        lo=0,
        hi=4,
        help="paper noise case: 1 Gaussian, 2 time-varying R (eqs. 29–31), 3 mixture outliers "
        "(eq. 32), 4 both; 0 = use the experiment's noise schedule and outlier model",
    )
    trajectory: str = param(
        "turning",
        choices=("turning", "static"),
        help="turning: level 10 m/s circle (yaw observable); static: at rest (yaw unobservable)",
    )
    dt: float = param(1.0, lo=0.01, hi=10.0, help="GPS interval T (s)")
    lat_deg: float = param(34.0, lo=-80.0, hi=80.0, help="latitude L0 (°)")
    h_m: float = param(380.0, lo=-500.0, hi=20000.0, help="height h0 (m)")
    speed_mps: float = param(10.0, lo=0.0, hi=300.0, help="turning: speed V (m/s)")
    turn_rate_radps: float = param(0.02, lo=0.0, hi=1.0, help="turning: turn rate Ω (rad/s)")
    sigma_pos_m: float = param(
        10.0,
        lo=0.01,
        hi=1000.0,
        help="nominal GPS σ on N, E, U (m); the paper's 10/Re rad read as 10 m on every axis",
    )
    arw_deg_rth: float = param(0.01, lo=0.0, hi=10.0, help="gyro angle random walk (°/√h)")
    vrw_ug_rhz: float = param(10.0, lo=0.0, hi=1e5, help="accelerometer velocity random walk (µg/√Hz)")
    gyro_rw_dph_rs: float = param(0.001, lo=0.0, hi=10.0, help="gyro-bias random walk ((°/h)/√s)")
    accel_rw_ug_rs: float = param(1.0, lo=0.0, hi=1e4, help="accelerometer-bias random walk (µg/√s)")
    p0_tilt_deg: float = param(0.1, lo=1e-6, hi=10.0, help="initial σ of φ_E, φ_N (°)")
    p0_yaw_deg: float = param(0.5, lo=1e-6, hi=30.0, help="initial σ of φ_U (°)")
    p0_vel_mps: float = param(0.1, lo=1e-6, hi=100.0, help="initial velocity-error σ (m/s)")
    p0_pos_m: float = param(10.0, lo=1e-3, hi=1e4, help="initial position-error σ (m)")
    p0_gyro_dph: float = param(0.1, lo=1e-6, hi=100.0, help="initial gyro-bias σ (°/h)")
    p0_accel_ug: float = param(100.0, lo=1e-3, hi=1e5, help="initial accelerometer-bias σ (µg)")
    gravity_gradient: bool = param(False, help="add δv̇_U += 2g/R·δh (omitted in the paper)")
    window_start: int = param(
        100,
        lo=0,
        hi=MAX_EPOCHS,
        help="metrics use epochs k ≥ this (paper plots settle by ≈100); runs shorter use all",
    )


def _trajectory(p: SinsGpsParams, t: Array) -> tuple[Array, Array, Array]:
    """Velocity v^n (N, 3), specific force f^n (N, 3) and C_b^n (N, 3, 3) at times t (§8.1)."""
    N = t.shape[0]
    g = float(normal_gravity(p.lat_deg * DEG, p.h_m))
    if p.trajectory == "static":
        V = W = 0.0
    else:
        V, W = p.speed_mps, p.turn_rate_radps
    psi = W * t
    s, c = np.sin(psi), np.cos(psi)
    v = V * np.stack([s, c, np.zeros(N)], axis=-1)
    f = np.stack([V * W * c, -V * W * s, np.full(N, g)], axis=-1)  # Coriolis neglected
    C = np.zeros((N, 3, 3))
    C[:, 0, 0], C[:, 0, 1], C[:, 1, 0], C[:, 1, 1], C[:, 2, 2] = c, s, -s, c, 1.0
    return v, f, C


def sins_gps_model(p: SinsGpsParams) -> tuple[Array, Array, Array, Array, Array]:
    """Per-epoch Φ_k, Q_k (K+1, 15, 15) for the transitions k−1 → k (index 0: identity, 0),
    H (3, 15), P0 (15, 15) and C_b^n (K+1, 3, 3).

    F is evaluated on the trajectory at t_{k−1} (L, h held constant) and discretised to second
    order (§8.0): Φ = I + FT + (FT)²/2, Q_d = ½(Φ G Qc Gᵀ Φᵀ + G Qc Gᵀ) T.
    """
    K = p.epochs
    t = np.arange(K + 1) * p.dt
    v, f, C = _trajectory(p, t)
    lat = np.full(K + 1, p.lat_deg * DEG)
    F, G = error_model_FG(lat, np.full(K + 1, p.h_m), v, f, C, gravity_gradient=p.gravity_gradient)
    Qc = np.diag(
        np.repeat(
            [
                (p.arw_deg_rth * DEG / 60.0) ** 2,
                (p.vrw_ug_rhz * UG) ** 2,
                (p.gyro_rw_dph_rs * DPH) ** 2,
                (p.accel_rw_ug_rs * UG) ** 2,
            ],
            3,
        )
    )
    Phi, Qd = discretise(F[:-1], G[:-1], Qc, p.dt)
    Phi = np.concatenate([np.eye(15)[None], Phi])
    Qd = np.concatenate([np.zeros((1, 15, 15)), Qd])
    H = np.zeros((3, 15))
    H[:, 6:9] = np.eye(3)
    sd = np.array(
        [
            *(p.p0_tilt_deg * DEG,) * 2,
            p.p0_yaw_deg * DEG,
            *(p.p0_vel_mps,) * 3,
            *(p.p0_pos_m,) * 3,
            *(p.p0_gyro_dph * DPH,) * 3,
            *(p.p0_accel_ug * UG,) * 3,
        ]
    )
    return Phi, Qd, H, np.diag(sd**2), C


def _scaled_sqrt(Q: Array) -> Array:
    """Lower factors L with L Lᵀ = Q for a stack of PSD matrices of very different scales.

    Cholesky of the diagonally normalised matrix (rad² and m² differ by 1e14), with a tiny
    jitter where a factorisation fails (a zero-variance state).
    """
    d = np.sqrt(np.maximum(np.diagonal(Q, axis1=-2, axis2=-1), 0.0))
    ds = np.where(d > 0, d, 1.0)
    Qs = Q / ds[..., :, None] / ds[..., None, :]
    n = Q.shape[-1]
    try:
        Ls = np.linalg.cholesky(Qs + 1e-14 * np.eye(n))
    except np.linalg.LinAlgError:
        Ls = np.linalg.cholesky(Qs + 1e-9 * np.eye(n))
    return ds[..., :, None] * Ls * (d > 0)[..., :, None]


def body_attitude_errors(x_hat: Array, x_true: Array, C_bn: Array, axis: int | None = None) -> Array:
    """Pitch, roll and heading errors (arcmin), (B, K+1, 3), by §9: φ^b = C_n^b φ^n.

    pitch = φ^b_x (about body right), roll = φ^b_y (about body forward), heading = −φ_U
    (ψ clockwise from north). ``axis`` 0, 1 or 2: that error alone, (B, K+1).
    """
    e = x_hat[..., 0:3] - x_true[..., 0:3]

    def one(i: int) -> Array:
        if i == 2:
            return -e[..., 2] * ARCMIN
        c = C_bn[:, :, i]  # φ^b_i = Σ_j (C_b^n)_ji φ^n_j  (C_n^b = (C_b^n)ᵀ)
        return (c[:, 0] * e[..., 0] + c[:, 1] * e[..., 1] + c[:, 2] * e[..., 2]) * ARCMIN

    return one(axis) if axis is not None else np.stack([one(i) for i in range(3)], axis=-1)


@register_scenario
class SinsGps(Scenario):
    key = "sins-gps"
    label = "SINS/GPS attitude (HAKF paper)"
    paper = "Zuo, Yin, Gao, Li 2017 (HAKF), §2"
    summary = (
        "15-state SINS error model aided by GPS position (σ 10 m); the HAKF paper's four cases: "
        "Gaussian, time-varying R, mixture outliers, both. Attitude errors in arcmin."
    )
    Params = SinsGpsParams
    outlier_defaults: ClassVar[dict[str, dict[str, Any]]] = {"mixture": {"contamination": 0.1, "scale": 10.0}}
    default_filters = ("kf", "huber-kf", "vb-akf", "hakf")
    pcrb = "linear"
    default_runs = 50
    headline = ("att", "vel", "pos")

    def noise_models(self, schedule: Schedule, outliers: OutlierModel) -> tuple[Schedule, OutlierModel]:
        """The schedule and outlier model actually used (``case`` 1–4 overrides the given ones)."""
        case = self.params.case
        if case == 0:
            return schedule, outliers
        sched_key, out_key = CASES[case]
        schedule = make_schedule(sched_key)
        if out_key == "none":
            outliers = make_outliers("none")
        elif not isinstance(outliers, Mixture):
            outliers = make_outliers("mixture", self.outlier_defaults["mixture"])
        return schedule, outliers

    def simulate(
        self, schedule: Schedule, outliers: OutlierModel, runs: Sequence[int], seed: int
    ) -> ScenarioData:
        p = self.params
        K = p.epochs
        schedule, outliers = self.noise_models(schedule, outliers)
        Phi, Qd, H, P0, C = sins_gps_model(p)
        streams = run_streams(seed, runs)
        B = len(streams)
        # truth: x_0 ~ N(0, P0); x_k = Φ_k x_{k−1} + w_k, w_k ~ N(0, Q_k)
        e0 = streams.truth.standard_normal(15)
        e = streams.truth.standard_normal((K, 15))
        x = propagate(e0 @ _scaled_sqrt(P0).T, Phi, e, _scaled_sqrt(Qd))
        r_nom = np.full(3, p.sigma_pos_m)
        std = schedule.std(r_nom, K)
        noise, var, bias, mask = draw_measurement_noise(streams, std, outliers)
        z = x @ H.T + noise
        z[:, 0] = np.nan
        # analysis window k ≥ 100 (§8.1); a run too short for it uses every epoch k ≥ 1
        window = np.arange(K + 1) >= (max(1, p.window_start) if p.window_start < K else 1)
        am = "arcmin"
        return ScenarioData(
            scenario=self.key,
            t=np.arange(K + 1) * p.dt,
            model=LinearModel(Phi, Qd, H, np.diag(r_nom**2)),
            x_true=x,
            z=z,
            R_true=var,
            R_schedule=std**2,
            outlier_mask=mask,
            bias=bias,
            x0=np.zeros((B, 15)),
            P0=P0,
            runs=np.asarray(runs),
            state_names=STATE_NAMES,
            channel_names=("p_N", "p_E", "p_U"),
            channel_units=("m", "m", "m"),
            groups={
                "att": MetricGroup((0, 1, 2), am, "attitude φ (E, N, U)", ARCMIN),
                "tilt": MetricGroup((0, 1), am, "level attitude φ_E, φ_N (pitch/roll)", ARCMIN),
                "phi_E": MetricGroup((0,), am, "φ_E", ARCMIN),
                "phi_N": MetricGroup((1,), am, "φ_N", ARCMIN),
                "phi_U": MetricGroup((2,), am, "heading φ_U", ARCMIN),
                "vel": MetricGroup((3, 4, 5), "m/s", "velocity"),
                "pos": MetricGroup((6, 7, 8), "m", "position"),
                "gyro_bias": MetricGroup((9, 10, 11), "°/h", "gyro bias", 1.0 / DPH),
                "accel_bias": MetricGroup((12, 13, 14), "µg", "accelerometer bias", 1.0 / UG),
            },
            window=window,
            extras={
                "C_bn": C,
                "case": p.case,
                "noise_schedule": schedule.key,
                "outliers": outliers.key,
                "trajectory": p.trajectory,
            },
        )
