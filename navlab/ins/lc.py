"""Loosely coupled INS/GNSS on a real drive: setup, a closed-loop 15-state EKF, and a Model.

Two ways to run the same 15-state loosely coupled filter are provided:

* :func:`run_closed_loop` — the textbook closed-loop error-state EKF (ALGORITHMS.md §8.0 error
  model, error = INS − truth, estimated errors fed back into the mechanisation after every
  update and the error state reset to zero). Batched over B solutions. It is used to build the
  linearisation reference and in the tests.
* :class:`InsGnssModel` — the same filter expressed as a nonlinear total-state model that every
  navlab filter can drive through the shared time loop (so the GNSS update can be any of the
  registered update strategies: KF, Huber, VB, Sage–Husa, IRAKF, χ² …). The state is

      x = [a (3, rad), v (3, ENU m/s), p (3, N E U m from the origin), b_g (3, rad/s), b_a (3, m/s²)]

  with the attitude ``C_b^n = exp(−[a×]) C_ref,k`` expressed relative to a reference attitude
  (so ``a`` stays small and the additive filter update equals the multiplicative attitude
  correction of the closed-loop filter), b_g / b_a the running bias estimates (the mechanisation
  subtracts them from every raw sample). ``f(x, k)`` runs the real strapdown mechanisation over
  the 100 Hz IMU samples of (t_{k−1}, t_k] from each filter's own x — the closed loop. The
  transition Jacobian ``F(k)`` is the §8.0 error model evaluated along the reference solution
  (a linearised KF about a nominal trajectory), with the bias signs flipped because the state
  holds the bias *estimates* (b̂ − b = −ε).

The reference solution is the closed-loop EKF aided by the RTK-fixed truth (σ = 5 cm). It is
used only as the linearisation point and as the chart for the attitude; the filters themselves
only see the noisy 1 Hz aiding.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from navlab.data.loaders import DriveRecording
from navlab.errors import NavlabError
from navlab.ins.align import AlignmentResult, align_static, course_heading, motion_start_time
from navlab.ins.earth import dcm_to_rotvec, radii, rotvec_to_dcm, skew
from navlab.ins.strapdown import (
    InsState,
    apply_correction,
    discretise,
    error_model_FG,
    init_state,
    propagate_block,
)
from navlab.linalg import Array

#: Sign flip between the §8.0 error state (ε = b − b̂) and the total state's bias estimates.
SIGN = np.diag(np.r_[np.ones(9), -np.ones(6)])
STATE_NAMES = (
    "a_E",
    "a_N",
    "a_U",
    "v_E",
    "v_N",
    "v_U",
    "p_N",
    "p_E",
    "p_U",
    "bg_x",
    "bg_y",
    "bg_z",
    "ba_x",
    "ba_y",
    "ba_z",
)


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time noise densities of the MEMS IMU (Qc of §8.0).

    Defaults from the rtkx static start, no truth involved (:func:`static_noise_densities`):
    the Allan deviation at τ = 1 s — the aiding interval — is 0.0008 / 0.0010 / 0.0028 rad/s
    (gyro x, y, z) and 0.054 / 0.016 / 0.015 m/s² (accelerometer), i.e. white-noise densities
    of ≈ 0.001 rad/√s and ≈ 0.016 m/s/√s (medians). The raw 100 Hz std (0.04 rad/s, 0.1 m/s²)
    is high-frequency vibration that averages out within a block and must not be used as the
    density (it overstated the ARW 5×). While driving, the mount vibrates far more (gyro y std
    5–15 °/s against 2 °/s at rest) and a vibrating MEMS gyro drifts (aliasing, rectification):
    ``vib_gyro_factor`` adds that share of each block's measured vibration (raw gyro std × √dt,
    :attr:`DriveSetup.vib_g`) to the ARW, so Q follows the vibration the IMU itself reports. The
    bias random walks are those of a consumer MEMS IMU (gyro ≈ 0.07 °/s, accelerometer ≈ 1 mg
    drift over 100 s). Measured on drive0708 (σ = 3 m, 3 runs): the old 0.005 rad/√s /
    0.03 m/s/√s gave the KF 1.96 m on clean aiding; a constant small ARW (0.001) makes the filter
    over-confident on this mount (ANEES > 40) and worse (2.25 m).
    """

    arw_rad_rts: float = 0.001  # angle random walk at rest [rad/√s]
    vrw_mps_rts: float = 0.015  # velocity random walk [m/s/√s]
    gyro_bias_rw: float = 2e-5  # gyro-bias random walk [rad/s/√s]
    accel_bias_rw: float = 1e-3  # accelerometer-bias random walk [m/s²/√s]
    vib_gyro_factor: float = 0.5  # share of the measured gyro vibration [rad/√s] added to the ARW

    def Qc(self, vib_g: float = 0.0) -> Array:
        """Continuous PSDs; ``vib_g`` = the block's gyro vibration (raw std × √dt) [rad/√s]."""
        arw = np.hypot(self.arw_rad_rts, self.vib_gyro_factor * float(vib_g))
        return np.diag(
            np.r_[
                [arw**2] * 3,
                [self.vrw_mps_rts**2] * 3,
                [self.gyro_bias_rw**2] * 3,
                [self.accel_bias_rw**2] * 3,
            ]
        )


def static_noise_densities(t_s: Array, f_b: Array, w_b: Array, tau_s: float = 1.0):
    """White-noise densities from a static window: Allan deviation at ``tau_s`` times √τ.

    Returns (gyro (3,) [rad/√s], accelerometer (3,) [m/s/√s]). At τ = the aiding interval this
    is the noise the filter actually integrates between fixes (the 100 Hz std is dominated by
    vibration that averages out and overstates it).
    """
    t = np.asarray(t_s, float)
    if t.size < 4 or t[-1] - t[0] < 4 * tau_s:
        raise NavlabError(f"the static window must be longer than {4 * tau_s:g} s for the Allan deviation")
    dt = float(np.median(np.diff(t)))
    n = max(1, round(tau_s / dt))
    out = []
    for x in (np.asarray(w_b, float), np.asarray(f_b, float)):
        m = len(x) // n
        a = x[: m * n].reshape(m, n, 3).mean(axis=1)
        out.append(np.sqrt(0.5 * np.mean(np.diff(a, axis=0) ** 2, axis=0)) * np.sqrt(n * dt))
    return out[0], out[1]


@dataclass(frozen=True, eq=False)
class DriveSetup:
    """A drive cut into aiding epochs, with the IMU in body axes and the initial alignment.

    Attributes
    ----------
    t : (K+1,) epoch times [s] (epoch 0 = end of the static alignment window).
    lat0_rad, lon0_rad, h0_m : origin of the local N, E, U metres.
    p_true : (K+1, 3) reference positions N, E, U [m] (NaN if no truth).
    v_true : (K+1, 3) reference velocities E, N, U [m/s] (NaN if unknown).
    gnss_pos : (K+1, 3) the recording's own GNSS positions N, E, U at the epochs.
    t_imu, f_b, w_b : IMU samples [s], [m/s²], [rad/s] (body axes).
    align : static alignment at epoch 0.
    x0 : (15,) initial total state; P0 : (15, 15).
    """

    t: Array
    lat0_rad: float
    lon0_rad: float
    h0_m: float
    p_true: Array
    v_true: Array
    gnss_pos: Array
    t_imu: Array
    f_b: Array
    w_b: Array
    align: AlignmentResult
    x0: Array
    P0: Array
    C0: Array
    C_bv: Array = field(default_factory=lambda: np.eye(3))
    vib_g: Array | None = None  # (K+1,) gyro vibration per block: rms raw std × √dt [rad/√s]

    @property
    def K(self) -> int:
        return len(self.t) - 1

    def to_local(self, lat_rad, lon_rad, h_m) -> Array:
        R_Mh, R_Nh = radii(self.lat0_rad, self.h0_m)
        return np.stack(
            [
                (np.asarray(lat_rad) - self.lat0_rad) * R_Mh,
                (np.asarray(lon_rad) - self.lon0_rad) * R_Nh * np.cos(self.lat0_rad),
                np.asarray(h_m) - self.h0_m,
            ],
            axis=-1,
        )

    def from_local(self, p: Array):
        R_Mh, R_Nh = radii(self.lat0_rad, self.h0_m)
        return (
            self.lat0_rad + p[..., 0] / R_Mh,
            self.lon0_rad + p[..., 1] / (R_Nh * np.cos(self.lat0_rad)),
            self.h0_m + p[..., 2],
        )

    def imu_slice(self, k: int) -> slice:
        """IMU samples with t_{k−1} ≤ t < t_k."""
        i0, i1 = np.searchsorted(self.t_imu, [self.t[k - 1], self.t[k]])
        return slice(int(i0), int(i1))


def expm_batched(A: Array) -> Array:
    """Matrix exponential of a stack (..., n, n): scaling and squaring with a 6th-order Taylor."""
    A = np.asarray(A, dtype=float)
    nrm = np.abs(A).sum(axis=-1).max()
    s = max(0, int(np.ceil(np.log2(max(nrm, 1e-300) / 0.25)))) if nrm > 0.25 else 0
    A = A / 2.0**s
    E = np.eye(A.shape[-1]) + A
    term = A
    for i in range(2, 7):
        term = term @ A / i
        E = E + term
    for _ in range(s):
        E = E @ E
    return E


def downsample_imu(t: Array, f: Array, w: Array, t0: float, rate_hz: float):
    """Average the raw samples over bins of 1/rate_hz starting at t0 (= summed Δv, Δθ increments).

    Each bin's sample is stamped at its start, so `propagate_block` holds it over the bin. A car
    turns < 1 rad/s, so coning/sculling over 50–100 ms bins is negligible; the mechanisation then
    runs 5–10× faster.
    """
    b = np.floor((t - t0) * rate_hz + 1e-9).astype(int)
    keep = b >= 0
    b, f, w = b[keep], f[keep], w[keep]
    uniq, start, cnt = np.unique(b, return_index=True, return_counts=True)
    fs = np.add.reduceat(f, start, axis=0) / cnt[:, None]
    ws = np.add.reduceat(w, start, axis=0) / cnt[:, None]
    return t0 + uniq / rate_hz, fs, ws


def velocity_lag_s(t_s: Array, p_neu: Array, v_enu: Array, max_lag_s: float = 0.3) -> float:
    """Delay [s] of a receiver's velocities behind the derivative of its own positions.

    Grid search (10 ms) of the lag minimising the rms of v(t) − ṗ(t − lag), ṗ from centred
    differences of the positions (N, E, U) of the same file; horizontal axes only.
    """
    t = np.asarray(t_s, float)
    vd = np.gradient(np.asarray(p_neu, float)[:, [1, 0]], t, axis=0)  # E, N
    v = np.asarray(v_enu, float)[:, :2]
    ok = np.isfinite(vd).all(axis=1) & np.isfinite(v).all(axis=1)
    if ok.sum() < 10:
        return 0.0
    t, vd, v = t[ok], vd[ok], v[ok]
    lags = np.arange(0.0, max_lag_s + 1e-9, 0.01)
    cost = [
        np.mean((v - np.stack([np.interp(t - lag, t, vd[:, i]) for i in range(2)], -1)) ** 2) for lag in lags
    ]
    return float(lags[int(np.argmin(cost))])


def prepare_drive(
    rec: DriveRecording,
    rate_hz: float = 1.0,
    epochs: int = 0,
    static_margin_s: float = 2.0,
    heading_deg: float | None = None,
    imu_rate_hz: float = 20.0,
) -> DriveSetup:
    """Cut a drive into aiding epochs and align the INS on the static start.

    Epoch 0 is ``static_margin_s`` before the vehicle starts moving (on the GNSS time grid);
    roll and pitch come from the mean static specific force, the gyro biases from the mean static
    rate, the heading from the GNSS course once moving (``heading_deg`` overrides it).
    """
    g = rec.gnss
    imu = rec.imu
    v_enu = g[["ve_mps", "vn_mps", "vu_mps"]].to_numpy()
    lat0, lon0, h0 = np.radians(g.lat_deg.iloc[0]), np.radians(g.lon_deg.iloc[0]), float(g.h_m.iloc[0])
    tg = g.t_s.to_numpy()
    vel_measured = not np.isnan(v_enu).all()
    if not vel_measured:  # generic files without velocity: smoothed differences of positions
        src = rec.truth if rec.truth is not None else g
        ts = src.t_s.to_numpy()
        R_Mh, R_Nh = radii(lat0, h0)
        pos = np.stack(
            [
                np.radians(src.lon_deg.to_numpy()) * R_Nh * np.cos(lat0),
                np.radians(src.lat_deg.to_numpy()) * R_Mh,
                src.h_m.to_numpy(),
            ],
            -1,
        )
        win = 2.0 if rec.truth is not None else 5.0  # s: noisy fixes need a longer baseline
        i1 = np.searchsorted(ts, ts + win / 2).clip(max=len(ts) - 1)
        i0 = np.searchsorted(ts, ts - win / 2)
        dt_ = np.maximum(ts[i1] - ts[i0], 1e-9)[:, None]
        v_src = (pos[i1] - pos[i0]) / dt_
        v_enu = np.stack([np.interp(tg, ts, v_src[:, i]) for i in range(3)], -1)
    t_move = motion_start_time(tg, v_enu, 0.3 if vel_measured else 1.0, 1.0 if vel_measured else 3.0)
    t_imu = imu.t_s.to_numpy()
    t_epoch0 = np.floor((t_move - static_margin_s) * rate_hz) / rate_hz
    t_epoch0 = max(t_epoch0, np.ceil(max(tg[0], t_imu[0]) * rate_hz) / rate_hz)
    t_end = min(tg[-1], t_imu[-1])
    K_avail = int(np.floor((t_end - t_epoch0) * rate_hz + 1e-9))
    if K_avail < 2:
        raise NavlabError("the drive is too short after the static start for a 1 Hz filter")
    K = K_avail if not epochs else min(int(epochs), K_avail)
    t = t_epoch0 + np.arange(K + 1) / rate_hz
    setup_origin = dict(lat0_rad=lat0, lon0_rad=lon0, h0_m=h0)
    R_Mh, R_Nh = radii(lat0, h0)

    def local(df):
        return np.stack(
            [
                (np.radians(df.lat_deg.to_numpy()) - lat0) * R_Mh,
                (np.radians(df.lon_deg.to_numpy()) - lon0) * R_Nh * np.cos(lat0),
                df.h_m.to_numpy() - h0,
            ],
            -1,
        )

    def interp(tt, x):
        return np.stack([np.interp(t, tt, x[:, i], left=np.nan, right=np.nan) for i in range(x.shape[1])], -1)

    gnss_pos = interp(tg, local(g))
    if rec.truth is not None:
        p_true = interp(rec.truth.t_s.to_numpy(), local(rec.truth))
        # the receiver's velocities lag its positions (rtkx: 0.12 s, 0.1 m/s rms): the velocity
        # truth is read at t + lag so that rmse_vel and NEES measure the filters, not the lag
        lag = velocity_lag_s(tg, local(g), v_enu) if vel_measured else 0.0
        t_v = np.minimum(t + lag, tg[-1])
        v_true = np.stack([np.interp(t_v, tg, v_enu[:, i], left=np.nan, right=np.nan) for i in range(3)], -1)
    else:
        p_true = np.full((K + 1, 3), np.nan)
        v_true = np.full((K + 1, 3), np.nan)
    f_b = imu[["f_x_mps2", "f_y_mps2", "f_z_mps2"]].to_numpy()
    w_b = imu[["w_x_radps", "w_y_radps", "w_z_radps"]].to_numpy()
    static = (t_imu < t_epoch0) & (t_imu >= t_imu[0])
    if static.sum() < 100:
        raise NavlabError(
            f"only {static.sum()} IMU samples before the vehicle moves (at {t_move:.1f} s); "
            "the recording must start with the vehicle at rest for at least 2 s"
        )
    if heading_deg is None:
        moving = (tg > t_move) & (np.hypot(v_enu[:, 0], v_enu[:, 1]) > (0.7 if vel_measured else 2.0))
        heading = float(course_heading(v_enu[np.flatnonzero(moving)[0]]))
    else:
        heading = np.radians(heading_deg)
    al = align_static(f_b[static], w_b[static], lat0, h0, heading, C_bv=rec.C_bv)
    # vibration per aiding block, from the raw samples (before they are averaged)
    dt_raw = float(np.median(np.diff(t_imu)))
    edges = np.searchsorted(t_imu, t)
    vib_g = np.zeros(K + 1)
    for k in range(1, K + 1):
        wk = w_b[edges[k - 1] : edges[k]]
        if len(wk) > 2:
            vib_g[k] = np.sqrt(np.mean(wk.var(axis=0)) * dt_raw)
    if imu_rate_hz:
        t_imu, f_b, w_b = downsample_imu(t_imu, f_b, w_b, float(t[0]), imu_rate_hz)
    p0 = gnss_pos[0] if np.isnan(p_true[0]).any() else p_true[0]
    # only the accelerometer bias along gravity is observable at rest: |f| − g along f
    ba0 = al.accel_norm_minus_gravity_mps2 * al.f_b_mean_mps2 / np.linalg.norm(al.f_b_mean_mps2)
    x0 = np.r_[np.zeros(3), np.zeros(3), p0, al.gyro_bias_radps, ba0]
    sig_head = 3.0 if vel_measured else 10.0  # deg: course from noisy fixes is rougher
    P0 = np.diag(
        np.r_[
            np.radians([0.5, 0.5, sig_head]) ** 2,
            [0.1**2] * 3,
            [1.0**2] * 3,
            [np.radians(0.05) ** 2] * 3,
            [0.1**2] * 3,
        ]
    )
    return DriveSetup(
        t=t,
        **setup_origin,
        p_true=p_true,
        v_true=v_true,
        gnss_pos=gnss_pos,
        t_imu=t_imu,
        f_b=f_b,
        w_b=w_b,
        align=al,
        x0=x0,
        P0=P0,
        C0=al.C_bn,
        C_bv=np.asarray(rec.C_bv, float),
        vib_g=vib_g,
    )


def _state_from_total(setup: DriveSetup, x: Array, C_ref: Array, t_s: float) -> InsState:
    lat, lon, h = setup.from_local(x[:, 6:9])
    C = rotvec_to_dcm(-x[:, 0:3]) @ C_ref
    return InsState(lat, lon, h, x[:, 3:6].copy(), C, x[:, 9:12].copy(), x[:, 12:15].copy(), t_s)


def _total_from_state(setup: DriveSetup, s: InsState, C_ref: Array) -> Array:
    a = -dcm_to_rotvec(s.C_bn @ np.swapaxes(C_ref, -1, -2))
    p = setup.to_local(s.lat_rad, s.lon_rad, s.h_m)
    return np.concatenate([a, s.v_enu_mps, p, s.bias_g_radps, s.bias_a_mps2], axis=-1)


@dataclass(frozen=True, eq=False)
class ClosedLoopResult:
    """Output of :func:`run_closed_loop`: (B, K+1, …) arrays on the epochs."""

    p: Array  # N, E, U [m]
    v: Array  # E, N, U [m/s]
    C_bn: Array  # (B, K+1, 3, 3)
    bias_g: Array
    bias_a: Array
    f_n_mean: Array  # (B, K+1, 3) mean ENU specific force over block k (k ≥ 1)
    P_diag: Array  # (B, K+1, 15)


def run_closed_loop(
    setup: DriveSetup, z: Array | None, sigma_m: float | Array, noise: ImuNoise = ImuNoise()
) -> ClosedLoopResult:
    """Closed-loop 15-state error-state EKF with position aiding (z=None: free INS).

    Parameters
    ----------
    setup : DriveSetup
    z : (B, K+1, 3) aiding positions N, E, U [m] (NaN = no fix), or None.
    sigma_m : position noise std [m] (scalar or (3,)).
    noise : IMU noise densities.
    """
    K = setup.K
    B = 1 if z is None else z.shape[0]
    s = init_state(
        *setup.from_local(np.broadcast_to(setup.x0[6:9], (B, 3))),
        np.zeros(3),
        np.broadcast_to(setup.C0, (B, 3, 3)),
        B=B,
        bias_g_radps=setup.x0[9:12],
        bias_a_mps2=setup.x0[12:15],
        t_s=setup.t[0],
    )
    P = np.broadcast_to(setup.P0, (B, 15, 15)).copy()
    R = np.diag(np.broadcast_to(np.asarray(sigma_m, float) ** 2, (3,)))
    H = np.zeros((3, 15))
    H[:, 6:9] = np.eye(3)
    vib = setup.vib_g if setup.vib_g is not None else np.zeros(K + 1)
    out = {
        k: np.full((B, K + 1, *shape), np.nan)
        for k, shape in (
            ("p", (3,)),
            ("v", (3,)),
            ("C", (3, 3)),
            ("bg", (3,)),
            ("ba", (3,)),
            ("fn", (3,)),
            ("Pd", (15,)),
        )
    }

    def record(k, s, P):
        out["p"][:, k] = setup.to_local(s.lat_rad, s.lon_rad, s.h_m)
        out["v"][:, k] = s.v_enu_mps
        out["C"][:, k] = s.C_bn
        out["bg"][:, k] = s.bias_g_radps
        out["ba"][:, k] = s.bias_a_mps2
        out["Pd"][:, k] = np.diagonal(P, axis1=-2, axis2=-1)

    record(0, s, P)
    for k in range(1, K + 1):
        sl = setup.imu_slice(k)
        s, blk = propagate_block(s, setup.t_imu[sl], setup.f_b[sl], setup.w_b[sl], t_end_s=setup.t[k])
        F, G = error_model_FG(s.lat_rad, s.h_m, s.v_enu_mps, blk.f_n_mean_mps2, s.C_bn)
        T = float(setup.t[k] - setup.t[k - 1])
        Phi = expm_batched(F * T)
        _, Qd = discretise(F, G, noise.Qc(vib[k]), T)
        P = Phi @ P @ np.swapaxes(Phi, -1, -2) + Qd
        out["fn"][:, k] = blk.f_n_mean_mps2
        if z is not None:
            zk = z[:, k]
            ok = np.isfinite(zk).all(axis=1)
            if ok.any():
                p_ins = setup.to_local(s.lat_rad, s.lon_rad, s.h_m)
                nu = np.where(ok[:, None], p_ins - np.nan_to_num(zk), 0.0)  # error-state innovation
                S = H @ P @ H.T + R
                Kg = np.linalg.solve(S, (P @ H.T).swapaxes(-1, -2)).swapaxes(-1, -2)
                Kg = Kg * ok[:, None, None]
                dx = (Kg @ nu[:, :, None])[:, :, 0]
                IKH = np.eye(15) - Kg @ H
                P = IKH @ P @ IKH.swapaxes(-1, -2) + Kg @ R @ Kg.swapaxes(-1, -2)
                s = apply_correction(s, dx)
        P = 0.5 * (P + P.swapaxes(-1, -2))
        record(k, s, P)
    return ClosedLoopResult(out["p"], out["v"], out["C"], out["bg"], out["ba"], out["fn"], out["Pd"])


class InsGnssModel:
    """Total-state loosely coupled INS/GNSS model for navlab's filters (see the module docstring).

    Measurements: GNSS positions z = p + v (N, E, U metres), R0 = diag(σ²), and, with
    ``nhc_sigma_mps`` > 0, the non-holonomic constraints of a car — zero velocity along the
    vehicle's right and up axes, z = 0 = [C_bv C_bnᵀ v]_{x,z} + v_nhc (two more channels).
    """

    n = 15
    linear = False

    def __init__(
        self,
        setup: DriveSetup,
        ref: ClosedLoopResult,
        sigma_m: Array,
        noise: ImuNoise = ImuNoise(),
        nhc_sigma_mps: float = 0.0,
    ) -> None:
        self.setup = setup
        self.C_ref = ref.C_bn[0]  # (K+1, 3, 3)
        self.nhc = nhc_sigma_mps > 0
        self.m = 5 if self.nhc else 3
        sig2 = np.asarray(sigma_m, float) ** 2
        self.R0 = np.diag(np.r_[sig2, [nhc_sigma_mps**2] * 2] if self.nhc else sig2)
        self._H = np.zeros((3, 15))
        self._H[:, 6:9] = np.eye(3)
        K = setup.K
        lat, _, h = setup.from_local(ref.p[0])
        self.Phi = np.empty((K + 1, 15, 15))
        self.Qd = np.empty((K + 1, 15, 15))
        self.Phi[0], self.Qd[0] = np.eye(15), np.zeros((15, 15))
        vib = setup.vib_g if setup.vib_g is not None else np.zeros(K + 1)
        for k in range(1, K + 1):
            F, G = error_model_FG(
                lat[k - 1], h[k - 1], ref.v[0, k - 1], ref.f_n_mean[0, k], self.C_ref[k - 1]
            )
            T = float(setup.t[k] - setup.t[k - 1])
            _, Qd = discretise(F, G, noise.Qc(vib[k]), T)
            self.Phi[k] = SIGN @ expm_batched(F[0] * T) @ SIGN
            self.Qd[k] = SIGN @ Qd[0] @ SIGN

    def F(self, k: int) -> Array:
        return self.Phi[k]

    def Q(self, k: int) -> Array:
        return self.Qd[k]

    def f(self, x: Array, k: int) -> Array:
        st = self.setup
        s = _state_from_total(st, x, self.C_ref[k - 1], float(st.t[k - 1]))
        sl = st.imu_slice(k)
        s, _ = propagate_block(s, st.t_imu[sl], st.f_b[sl], st.w_b[sl], t_end_s=float(st.t[k]))
        return _total_from_state(st, s, self.C_ref[k])

    def _C_vn(self, x: Array, k: int) -> Array:
        """(B, 3, 3) rotation ENU -> vehicle, C_bv C_bnᵀ with C_bn = exp(−[a×]) C_ref,k."""
        C_bn = rotvec_to_dcm(-x[:, 0:3]) @ self.C_ref[k]
        return self.setup.C_bv @ np.swapaxes(C_bn, -1, -2)

    def H(self, x: Array | None, k: int) -> Array:
        if not self.nhc:
            return self._H
        B = x.shape[0]
        Cvn = self._C_vn(x, k)[:, [0, 2]]  # right and up rows
        H = np.zeros((B, 5, 15))
        H[:, 0:3, 6:9] = np.eye(3)
        H[:, 3:5, 3:6] = Cvn
        # C_bnᵀ v = C_refᵀ exp([a×]) v ≈ C_refᵀ (v + a × v) → ∂/∂a = −C_vn [v×]
        H[:, 3:5, 0:3] = -Cvn @ skew(x[:, 3:6])
        return H

    def h(self, x: Array, k: int) -> Array:
        if not self.nhc:
            return x[:, 6:9]
        v_v = (self._C_vn(x, k) @ x[:, 3:6, None])[:, :, 0]
        return np.concatenate([x[:, 6:9], v_v[:, [0, 2]]], axis=1)


#: Process noise of the reference solution: looser than the filters' (it is aided at 5 cm and must
#: follow every real attitude change of the vibrating mount rather than smooth over it).
REFERENCE_NOISE = ImuNoise(
    arw_rad_rts=0.005, vrw_mps_rts=0.03, gyro_bias_rw=2e-5, accel_bias_rw=2e-3, vib_gyro_factor=0.0
)


def reference_solution(setup: DriveSetup, noise: ImuNoise = REFERENCE_NOISE) -> ClosedLoopResult:
    """Closed-loop EKF aided by the truth positions (σ = 5 cm): the linearisation reference.

    Without truth, the recording's own GNSS positions are used (σ = 2 m).
    """
    if np.isfinite(setup.p_true).all(axis=1).mean() > 0.5:
        return run_closed_loop(setup, setup.p_true[None], 0.05, noise)
    return run_closed_loop(setup, setup.gnss_pos[None], 2.0, noise)


__all__ = [
    "STATE_NAMES",
    "ClosedLoopResult",
    "DriveSetup",
    "ImuNoise",
    "InsGnssModel",
    "prepare_drive",
    "reference_solution",
    "run_closed_loop",
    "static_noise_densities",
    "velocity_lag_s",
]
