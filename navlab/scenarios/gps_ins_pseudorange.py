"""8-state GPS/INS with pseudorange measurements and a time-varying R (Hou et al. 2024, §4).

ALGORITHMS.md §8.4. The paper (a UAV, EKF vs VB-EKF) gives the state, the start point, the clock
initial values, 1 s sampling and 200 s, but no satellite geometry, noise level or interference
model; navlab's reconstruction (§8.4, §10 #33–#38):

* state x = [δN, δE, δU (m), δV_E, δV_N, δV_U (m/s), c_b (m), c_d (m/s)] — the paper's order
  [δL, δλ, δh, δV_E, δV_N, δV_U, c_b, c_d] with the position errors in metres (§0.2 rule 4). Note
  the mixed order: position N, E, U but velocity E, N, U, so the position–velocity block of F is
  T·[[0,1,0],[1,0,0],[0,0,1]];
* velocity errors are random walks driven by white acceleration noise (PSD q_a per axis); clock
  bias/drift the two-state TCXO model;
* 8 satellites fixed in azimuth/elevation; the measurement is the pseudorange error
  z_j = ρ_j^GPS − ρ_j(r^INS) = ‖d_j + δr‖ − ‖d_j‖ + c_b + v_j (d_j = user→satellite vector,
  δr = INS position error), a nonlinear h with Jacobian row [u_N, u_E, u_U, 0, 0, 0, 1, 0];
* "external interference": satellites 2, 4 and 7 (low elevation) get σ_j(t) = σ0 (1 + 9 b(t)),
  b(t) = ½[tanh((t − 50)/5) − tanh((t − 150)/5)], a smooth 10× burst from ≈50 s to ≈150 s.
  The foundation's noise schedule and outlier model act on top of it (constant/none: the paper).

The truth is simulated in the error state (§8): x^true_k = F x^true_{k−1} + w, z = h(x^true) + v.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from navlab.errors import NavlabError
from navlab.linalg import Array
from navlab.noise import OutlierModel, Schedule
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

# Hou et al. 2024 §4: start point and clock initial values (read as m and m/s, §10 #33)
LAT0_DEG, LON0_DEG, H0_M = 40.13, 118.66, 100.0
CB0_M, CD0_MPS = 3.575261153706439e2, 0.4549246345845814
# §8.4: 8 GPS satellites (azimuth, elevation) in degrees, fixed for the 200 s
SAT_AZ_EL_DEG = np.array(
    [(10, 75), (60, 35), (110, 55), (160, 20), (205, 45), (250, 65), (300, 25), (335, 40)], float
)
R_SAT_M = 26_560e3  # GPS orbit radius
WGS84_A, WGS84_E2 = 6_378_137.0, 6.69437999014e-3

STATE_NAMES = ("δN", "δE", "δU", "δV_E", "δV_N", "δV_U", "c_b", "c_d")
# ENU component of each position-error state (δN, δE, δU): e = 1 -> N ... see _enu
_POS_ENU = (1, 0, 2)  # δr_ENU = x[[δE, δN, δU]] = x[[1, 0, 2]]


def lla_to_ecef(lat_deg: float, lon_deg: float, h: float) -> Array:
    """WGS-84 geodetic → ECEF (m)."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    N = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
    return np.array(
        [
            (N + h) * np.cos(lat) * np.cos(lon),
            (N + h) * np.cos(lat) * np.sin(lon),
            (N * (1 - WGS84_E2) + h) * np.sin(lat),
        ]
    )


def enu_to_ecef_matrix(lat_deg: float, lon_deg: float) -> Array:
    """Columns: the E, N, U unit vectors in ECEF."""
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    return np.array([[-so, -sl * co, cl * co], [co, -sl * so, cl * so], [0.0, cl, sl]])


def satellite_geometry(az_el_deg: Array) -> tuple[Array, Array, Array]:
    """Unit LOS (ENU), ranges (m) and ECEF positions of satellites at the start point.

    u_j = [cos el sin az, cos el cos az, sin el] (user → satellite, ENU); the range puts the
    satellite at |r_sat| = 26 560 km (§8.4).
    """
    az, el = np.radians(az_el_deg[:, 0]), np.radians(az_el_deg[:, 1])
    los = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=1)
    r_user = lla_to_ecef(LAT0_DEG, LON0_DEG, H0_M)
    u_ecef = los @ enu_to_ecef_matrix(LAT0_DEG, LON0_DEG).T
    b = u_ecef @ r_user
    rng_m = -b + np.sqrt(b**2 - (r_user @ r_user - R_SAT_M**2))
    return los, rng_m, r_user + rng_m[:, None] * u_ecef


def pseudorange_matrices(dt: float, q_a: float, S_b: float, S_d: float) -> tuple[Array, Array]:
    """F and Q of the 8-state model (§8.4), state order [δN, δE, δU, δV_E, δV_N, δV_U, c_b, c_d]."""
    F = np.eye(8)
    Q = np.zeros((8, 8))
    qb = q_a * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    # mixed order: δN' = δV_N, δE' = δV_E, δU' = δV_U (NOT F = [[I, T·I], [0, I]])
    for p, v in ((0, 4), (1, 3), (2, 5)):
        F[p, v] = dt
        Q[np.ix_((p, v), (p, v))] = qb
    F[6, 7] = dt  # ċ_b = c_d + w_b
    Q[6:, 6:] = [[S_b * dt + S_d * dt**3 / 3, S_d * dt**2 / 2], [S_d * dt**2 / 2, S_d * dt]]
    return F, Q


@dataclass(frozen=True, eq=False)
class PseudorangeModel:
    """Nonlinear pseudorange-error model (the :class:`~navlab.filters.base.Model` protocol).

    ``d`` (m, 3) are the user → satellite vectors (ENU, m); h and its Jacobian are exact.
    """

    F_: Array
    Q_: Array
    R0: Array
    d: Array
    linear: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "rho", np.linalg.norm(self.d, axis=1))  # ‖d_j‖ (m,)
        object.__setattr__(self, "dT2", 2.0 * self.d.T)  # (3, m)

    @property
    def n(self) -> int:
        return 8

    @property
    def m(self) -> int:
        return int(self.d.shape[0])

    def F(self, k: int) -> Array:
        return self.F_

    def Q(self, k: int) -> Array:
        return self.Q_

    def f(self, x: Array, k: int) -> Array:
        return x @ self.F_.T

    def h(self, x: Array, k: int) -> Array:
        """h_j(x) = ‖d_j + δr‖ − ‖d_j‖ + c_b, evaluated without cancellation (B, m)."""
        dr = x[..., _POS_ENU]  # (B, 3) INS position error, ENU
        rho = self.rho
        num = dr @ self.dT2 + np.sum(dr * dr, axis=-1, keepdims=True)
        # ‖d+δr‖ − ‖d‖ = (2 d·δr + |δr|²) / (‖d+δr‖ + ‖d‖)
        return num / (np.sqrt(rho**2 + num) + rho) + x[..., 6:7]

    def H(self, x: Array, k: int) -> Array:
        """Jacobian at x: row j = [u_N, u_E, u_U, 0, 0, 0, 1, 0] with u = (d_j+δr)/‖d_j+δr‖."""
        v = self.d + x[..., None, _POS_ENU]  # (B, m, 3)
        u = v / np.linalg.norm(v, axis=-1, keepdims=True)
        H = np.zeros((*x.shape[:-1], self.m, 8))
        H[..., 0] = u[..., 1]  # δN ← north component
        H[..., 1] = u[..., 0]  # δE ← east component
        H[..., 2] = u[..., 2]
        H[..., 6] = 1.0
        return H


def interference_factor(
    t: Array, m: int, sats: Sequence[int], factor: float, start: float, stop: float, edge: float
) -> Array:
    """σ multiplier (len(t), m): 1 + (factor − 1) b(t) on ``sats``, 1 elsewhere (§8.4)."""
    if stop <= start:
        raise NavlabError("scenario 'gps-ins-pseudorange': burst_stop must be later than burst_start")
    if edge > 0:
        b = 0.5 * (np.tanh((t - start) / edge) - np.tanh((t - stop) / edge))
    else:
        b = ((t >= start) & (t <= stop)).astype(float)
    g = np.ones((t.size, m))
    g[:, list(sats)] = 1.0 + (factor - 1.0) * b[:, None]
    return g


def display_trajectory(t: Array) -> Array:
    """Display-only ENU path (m): v = (15, 20, 0) m/s, a 90° right turn over 100–120 s."""
    az = np.radians(np.degrees(np.arctan2(15.0, 20.0)) + 90.0 * np.clip((t - 100.0) / 20.0, 0, 1))
    v = 25.0 * np.stack([np.sin(az), np.cos(az), np.zeros_like(az)], axis=1)
    p = np.zeros_like(v)
    if t.size > 1:
        p[1:] = np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t)[:, None], axis=0)
    p[:, 2] = H0_M
    return p


@dataclass(frozen=True)
class PseudorangeParams:
    epochs: int = param(200, lo=2, hi=MAX_EPOCHS, help="number of epochs K (paper: 200 s at 1 s)")
    dt: float = param(1.0, lo=0.01, hi=10.0, help="sampling interval T (s)")
    q_a: float = param(0.1, lo=0.0, hi=100.0, help="velocity random-walk PSD per axis (m²/s³)")
    S_b: float = param(0.009, lo=0.0, hi=100.0, help="clock-bias PSD (m²/s), TCXO")
    S_d: float = param(0.0355, lo=0.0, hi=100.0, help="clock-drift PSD (m²/s³), TCXO")
    sigma0: float = param(3.0, lo=0.01, hi=1000.0, help="nominal pseudorange σ0 (m), all sats")
    interference: float = param(
        10.0, lo=1.0, hi=1000.0, help="σ multiplier of the interference burst (1 = no burst)"
    )
    burst_start: float = param(50.0, lo=0.0, hi=1e6, help="burst centre-of-rise (s)")
    burst_stop: float = param(150.0, lo=0.0, hi=1e6, help="burst centre-of-fall (s)")
    burst_edge: float = param(5.0, lo=0.0, hi=1e5, help="tanh edge width (s); 0 = sharp")
    interfered: tuple = param(
        (1, 3, 6),
        help="interfered satellite indices (0-based; default = satellites 2, 4, 7)",
        ui=False,
    )
    p0_pos: float = param(10.0, lo=1e-3, hi=1e5, help="initial position σ per axis (m)")
    p0_vel: float = param(1.0, lo=1e-3, hi=1e4, help="initial velocity σ per axis (m/s)")
    p0_cb: float = param(10.0, lo=1e-3, hi=1e5, help="initial clock-bias σ (m)")
    p0_cd: float = param(1.0, lo=1e-3, hi=1e4, help="initial clock-drift σ (m/s)")


@register_scenario
class GpsInsPseudorange(Scenario):
    key = "gps-ins-pseudorange"
    label = "GPS/INS pseudoranges with interference (UAV, 8 states)"
    paper = "Hou et al. 2024 (VB-EKF), §4"
    summary = (
        "A UAV's INS errors and receiver clock estimated from 8 satellite pseudoranges (σ 3 m). "
        "From ≈50 s to ≈150 s interference raises the noise of 3 low satellites 10×: "
        "the EKF keeps trusting them, the VB-EKF learns their R."
    )
    Params = PseudorangeParams
    # the paper has no outliers: keep the default spec (mixture) clean unless asked for
    outlier_defaults: ClassVar[dict[str, dict[str, Any]]] = {"mixture": {"contamination": 0.0}}
    default_filters = ("ekf", "vb-ekf", "oracle-kf")
    pcrb = "monte-carlo"
    default_runs = 50
    headline = ("pos", "vel")

    def simulate(
        self, schedule: Schedule, outliers: OutlierModel, runs: Sequence[int], seed: int
    ) -> ScenarioData:
        p = self.params
        K = p.epochs
        m = SAT_AZ_EL_DEG.shape[0]
        bad = [s for s in p.interfered if not 0 <= int(s) < m or int(s) != s]
        if bad:
            raise NavlabError(
                f"scenario '{self.key}': interfered satellite(s) {bad} do not exist; use 0 … {m - 1}"
            )
        F, Q = pseudorange_matrices(p.dt, p.q_a, p.S_b, p.S_d)
        los, ranges, sat_ecef = satellite_geometry(SAT_AZ_EL_DEG)
        R0 = p.sigma0**2 * np.eye(m)
        model = PseudorangeModel(F, Q, R0, ranges[:, None] * los)
        P0 = np.diag(np.array([p.p0_pos] * 3 + [p.p0_vel] * 3 + [p.p0_cb, p.p0_cd]) ** 2)
        x_hat0 = np.array([0.0] * 6 + [CB0_M, CD0_MPS])

        streams = run_streams(seed, runs)
        B = len(streams)
        # truth error state: x_0 ~ N([0, …, c_b0, c_d0], P0); x_k = F x_{k−1} + w, w ~ N(0, Q)
        wq, Vq = np.linalg.eigh(Q)
        LQ = Vq * np.sqrt(np.clip(wq, 0.0, None))  # Q = LQ LQᵀ (Q may be singular)
        e0 = streams.truth.standard_normal(8)
        x = propagate(x_hat0 + np.sqrt(np.diag(P0)) * e0, F, streams.truth.standard_normal((K, 8)), LQ)
        x0 = np.broadcast_to(x_hat0, (B, 8)).copy()

        t = np.arange(K + 1) * p.dt
        g = interference_factor(
            t,
            m,
            [int(s) for s in p.interfered],
            p.interference,
            p.burst_start,
            p.burst_stop,
            p.burst_edge,
        )
        std = p.sigma0 * g * schedule.std(np.ones(m), K)  # the foundation's schedule on top
        noise, var, bias, mask = draw_measurement_noise(streams, std, outliers)
        z = model.h(x.reshape(-1, 8), 0).reshape(B, K + 1, m) + noise
        z[:, 0] = np.nan
        names = tuple(f"sat {j + 1} (az {a:.0f}°, el {e:.0f}°)" for j, (a, e) in enumerate(SAT_AZ_EL_DEG))
        return ScenarioData(
            scenario=self.key,
            t=t,
            model=model,
            x_true=x,
            z=z,
            R_true=var,
            R_schedule=std**2,
            outlier_mask=mask,
            bias=bias,
            x0=x0,
            P0=P0,
            runs=np.asarray(runs),
            state_names=STATE_NAMES,
            channel_names=names,
            channel_units=("m",) * m,
            groups={
                "pos": MetricGroup((0, 1, 2), "m", "position (3-D)"),
                "vel": MetricGroup((3, 4, 5), "m/s", "velocity (3-D)"),
                "pos_h": MetricGroup((0, 1), "m", "horizontal position"),
                "pos_n": MetricGroup((0,), "m", "north position"),
                "pos_e": MetricGroup((1,), "m", "east position"),
                "pos_u": MetricGroup((2,), "m", "up position"),
                "clock_bias": MetricGroup((6,), "m", "clock bias c·δt"),
                "clock_drift": MetricGroup((7,), "m/s", "clock drift"),
            },
            window=np.arange(K + 1) >= 1,
            extras={
                "sat_az_el_deg": SAT_AZ_EL_DEG.copy(),
                "sat_ecef_m": sat_ecef,
                "user_lla0": (LAT0_DEG, LON0_DEG, H0_M),
                "interfered": tuple(int(s) for s in p.interfered),
                "trajectory_enu_m": display_trajectory(t),
            },
        )
