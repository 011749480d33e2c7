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

import itertools
from dataclasses import dataclass, field

import numpy as np

from navlab.data.loaders import DriveRecording
from navlab.errors import NavlabError
from navlab.ins.align import AlignmentResult, align_moving, align_static, course_heading, motion_start_time
from navlab.ins.earth import (
    _DCM_TO_ROTVEC,
    _ROTVEC_TO_DCM,
    _dcm_to_rotvec_runs,
    _rotvec_to_dcm_runs,
    dcm_to_rotvec,
    radii,
    rotvec_to_dcm,
    skew,
)
from navlab.ins.strapdown import (
    _MECHANISE_RUN,
    InsState,
    _mechanise_run,
    apply_correction,
    discretise,
    error_model_FG,
    init_state,
    propagate_block,
)
from navlab.jit import Kernel, carray
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

    def Qc(self, vib_g: float | Array = 0.0) -> Array:
        """Continuous PSDs (12, 12); ``vib_g`` = the block's gyro vibration (raw std × √dt)
        [rad/√s], a scalar or one per block (K,) -> (K, 12, 12).
        """
        arw = np.hypot(self.arw_rad_rts, self.vib_gyro_factor * np.asarray(vib_g, dtype=float))
        one = np.ones_like(arw)
        d = [arw**2] * 3 + [self.vrw_mps_rts**2 * one] * 3
        d += [self.gyro_bias_rw**2 * one] * 3 + [self.accel_bias_rw**2 * one] * 3
        return _diag_stack(d)


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


#: A priori PSDs of the motion the INS does not see while the IMU is silent (a bridged gap): a car
#: accelerates by up to ≈ 2 m/s² and turns at up to ≈ 0.2 rad/s (11 °/s) in ordinary driving.
GAP_ACCEL_MPS2 = 2.0
GAP_RATE_RADPS = 0.2


def gap_Qc(gap_share: float | Array) -> Array:
    """Extra continuous PSD (12×12, the noise inputs of ``ImuNoise.Qc``: gyro, accelerometer white
    noise, then the two bias random walks) for the share of an aiding interval the IMU did not
    cover: the INS coasts on interpolated samples there while the vehicle may accelerate or turn.
    One per block for an array of shares (K,) -> (K, 12, 12).
    """
    g = np.asarray(gap_share, dtype=float)
    d = [GAP_RATE_RADPS**2 * g] * 3 + [GAP_ACCEL_MPS2**2 * g] * 3 + [0.0 * g] * 6
    return _diag_stack(d)


def _diag_stack(d: list[Array]) -> Array:
    """Diagonal matrices (..., n, n) from n diagonal entries of equal shape (...)."""
    D = np.stack(d, axis=-1)
    out = np.zeros((*D.shape, D.shape[-1]))
    idx = np.arange(D.shape[-1])
    out[..., idx, idx] = D
    return out


def bridge_gaps(t: Array, f: Array, w: Array, factor: float = 5.0, min_gap_s: float = 0.05):
    """Fill IMU time gaps by linear interpolation on the nominal sample interval.

    A gap is an interval longer than ``factor`` times the median interval and ``min_gap_s``.
    Returns ``(t, f, w, gaps)`` with ``gaps`` a list of ``(start_s, length_s)``. The strapdown
    mechanisation then coasts through the gap on interpolated samples; the caller raises the
    process noise over it (:func:`gap_Qc`) because the INS does not know what happened there.
    """
    t = np.asarray(t, float)
    d = np.diff(t)
    if d.size == 0:
        return t, f, w, []
    dt = float(np.median(d))
    big = np.flatnonzero(d > max(factor * dt, min_gap_s))
    if not big.size:
        return t, f, w, []
    gaps = [(float(t[i]), float(d[i])) for i in big]
    t_new = [np.arange(t[i] + dt, t[i + 1] - 0.5 * dt, dt) for i in big]
    tt = np.concatenate([t, *t_new])
    order = np.argsort(tt, kind="stable")
    tt = tt[order]
    ff = np.stack([np.interp(tt, t, f[:, j]) for j in range(3)], -1)
    ww = np.stack([np.interp(tt, t, w[:, j]) for j in range(3)], -1)
    return tt, ff, ww, gaps


def gap_time_per_block(t_epochs: Array, gaps: list[tuple[float, float]]) -> Array:
    """Seconds of bridged IMU gap inside each aiding interval (t_{k−1}, t_k]: (K+1,)."""
    out = np.zeros(len(t_epochs))
    for g0, L in gaps:
        g1 = g0 + L
        lo = np.maximum(t_epochs[:-1], g0)
        hi = np.minimum(t_epochs[1:], g1)
        out[1:] += np.clip(hi - lo, 0.0, None)
    return out


@dataclass(frozen=True, eq=False)
class DriveSetup:
    """A drive cut into aiding epochs, with the IMU in body axes and the initial alignment.

    Attributes
    ----------
    t : (K+1,) epoch times [s] (epoch 0 = the start of the filters).
    lat0_rad, lon0_rad, h0_m : origin of the local N, E, U metres.
    p_true : (K+1, 3) reference positions N, E, U [m] of the GNSS antenna (NaN if no truth).
    v_true : (K+1, 3) reference velocities E, N, U [m/s] (NaN if unknown).
    gnss_pos : (K+1, 3) the recording's own GNSS positions N, E, U at the epochs (NaN: no fix).
    gnss_sigma : (K+1, 3) the receiver's 1-σ of those fixes, N, E, U [m] (NaN: not given).
    t_imu, f_b, w_b : IMU samples [s], [m/s²], [rad/s] (body axes).
    align : alignment at epoch 0 (static or in motion, see ``start``).
    x0 : (15,) initial total state; P0 : (15, 15).
    start : "static" (aligned on a static segment) or "moving" (initialised from GNSS).
    lever_arm_v : (3,) GNSS antenna relative to the IMU in the vehicle frame (right, forward, up) [m].
    gap_s : (K+1,) seconds of bridged IMU gap per aiding interval.
    notes : plain-words remarks made while preparing (gaps bridged, seconds skipped …).
    gnss_time_offset_s : the offset added to the GNSS time stamps.
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
    gnss_sigma: Array | None = None
    start: str = "static"
    lever_arm_v: Array = field(default_factory=lambda: np.zeros(3))
    gap_s: Array | None = None
    notes: tuple[str, ...] = ()
    gnss_time_offset_s: float = 0.0

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
    """Matrix exponential of a stack (..., n, n): scaling and squaring with a 6th-order Taylor.

    Each matrix is scaled by its own 2^s (s from its ∞-norm) and squared s times, so a matrix
    gets the same numbers alone or in a stack.
    """
    A = np.asarray(A, dtype=float)
    nrm = np.abs(A).sum(axis=-1).max(axis=-1)  # ∞-norm of each matrix
    s = np.where(nrm > 0.25, np.ceil(np.log2(np.maximum(nrm, 1e-300) / 0.25)), 0.0)
    s = np.maximum(s, 0.0).astype(int)
    A = A / (2.0**s)[..., None, None]
    E = np.eye(A.shape[-1]) + A
    term = A
    for i in range(2, 7):
        term = term @ A / i
        E = E + term
    for j in range(int(s.max(initial=0))):
        E = np.where((s > j)[..., None, None], E @ E, E)
    return E


def imu_on_epochs(t: Array, f: Array, w: Array, t_epochs: Array, rate_hz: float):
    """The IMU as held samples on intervals that never straddle an aiding epoch: (t, f, w).

    The raw samples are a zero-order hold (sample i held over [t_i, t_{i+1}), the last one for
    the median interval), exactly as :func:`navlab.ins.strapdown.propagate_block` integrates
    them. Output sample j is the exact mean of that signal over [e_j, e_{j+1}) (the summed Δv, Δθ
    increments divided by the length), with edges e at every epoch time and, between two epochs,
    either a grid of 1/``rate_hz`` starting AT the earlier epoch, or (``rate_hz`` = 0) the raw
    sample times. Every block (t_{k−1}, t_k] therefore starts with its own sample at t_{k−1}: each
    GNSS fix is applied at its own time stamp whatever the GNSS rate and jitter, and averaging
    (``rate_hz`` > 0) only merges samples inside one block. A car turns < 1 rad/s, so the
    coning/sculling lost over 50–100 ms bins is negligible, and the mechanisation has fewer steps.
    Samples before the first epoch are dropped (the alignment reads the raw ones).
    """
    t = np.asarray(t, float)
    te = np.asarray(t_epochs, float)
    x = np.concatenate([np.asarray(f, float), np.asarray(w, float)], axis=1)
    dt_raw = np.diff(t)
    hold = np.r_[dt_raw, np.median(dt_raw) if dt_raw.size else 0.0]
    t_ext = np.r_[t, t[-1] + hold[-1]]
    cum = np.vstack([np.zeros((1, 6)), np.cumsum(x * hold[:, None], axis=0)])  # ∫ x dt at t_ext
    if rate_hz and rate_hz > 0:
        step = 1.0 / float(rate_hz)
        n = np.maximum(np.ceil((np.diff(te) - 1e-9) / step).astype(int), 1)
        edges = np.repeat(te[:-1], n) + step * (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n))
    else:
        inner = t[(t > te[0]) & (t < te[-1])]
        j = np.searchsorted(te, inner)
        inner = inner[np.minimum(inner - te[j - 1], te[j] - inner) > 1e-9]  # none within 1 ns of an epoch
        edges = np.union1d(te[:-1], inner)
    edges = np.r_[edges, te[-1]]
    C = np.stack([np.interp(edges, t_ext, cum[:, i]) for i in range(6)], -1)
    x_mean = np.diff(C, axis=0) / np.diff(edges)[:, None]
    return edges[:-1], x_mean[:, :3], x_mean[:, 3:]


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


def differenced_velocity(t: Array, pos_enu: Array, window_s: float) -> Array:
    """ENU velocity from centred differences of positions over ``window_s`` (ends one-sided)."""
    i1 = np.searchsorted(t, t + window_s / 2).clip(max=len(t) - 1)
    i0 = np.searchsorted(t, t - window_s / 2)
    dt_ = np.maximum(t[i1] - t[i0], 1e-9)[:, None]
    return (pos_enu[i1] - pos_enu[i0]) / dt_


def interp_with_gaps(t_out: Array, t_in: Array, x: Array, max_gap_s: float) -> Array:
    """Linear interpolation of x (N, d) at t_out; NaN outside t_in or inside gaps > ``max_gap_s``."""
    out = np.stack(
        [np.interp(t_out, t_in, x[:, i], left=np.nan, right=np.nan) for i in range(x.shape[1])], -1
    )
    j = np.searchsorted(t_in, t_out).clip(1, len(t_in) - 1)
    span = t_in[j] - t_in[j - 1]
    exact = np.isclose(t_in[j - 1], t_out) | np.isclose(t_in[j], t_out)
    out[(span > max_gap_s) & ~exact] = np.nan
    return out


#: Speed [m/s] above which the GNSS course is the vehicle heading (measured velocities / velocities
#: differenced from fixes), and the shortest static segment aligned on [s].
HEADING_SPEED_MPS = (2.0, 3.0)
MIN_STATIC_S = 2.0


def _local_metres(df, lat0: float, lon0: float, h0: float) -> Array:
    """Positions N, E, U [m] of a lat/lon/h table relative to the origin (lat0, lon0 [rad], h0 [m])."""
    R_Mh, R_Nh = radii(lat0, h0)
    return np.stack(
        [
            (np.radians(df.lat_deg.to_numpy()) - lat0) * R_Mh,
            (np.radians(df.lon_deg.to_numpy()) - lon0) * R_Nh * np.cos(lat0),
            df.h_m.to_numpy() - h0,
        ],
        -1,
    )


@dataclass(frozen=True, eq=False)
class _GnssTrack:
    """The recording's GNSS fixes in local metres, with ENU velocities for the start and the heading.

    Attributes
    ----------
    t : (N,) fix times [s] (with the GNSS time offset).
    p : (N, 3) positions N, E, U [m].
    v_enu : (N, 3) velocities E, N, U [m/s]: measured, else differenced from positions.
    speed : (N,) horizontal speed [m/s].
    measured : the recording has its own velocities (for > 90 % of the fixes).
    """

    t: Array
    p: Array
    v_enu: Array
    speed: Array
    measured: bool


def _gnss_track(
    rec: DriveRecording, gnss_time_offset_s: float, origin: tuple[float, float, float]
) -> _GnssTrack:
    """The GNSS fixes of ``rec`` in local metres with velocities (differenced when not recorded)."""
    g = rec.gnss
    tg = g.t_s.to_numpy() + float(gnss_time_offset_s)
    v_enu = g[["ve_mps", "vn_mps", "vu_mps"]].to_numpy()
    p_g = _local_metres(g, *origin)
    vel_measured = bool(np.isfinite(v_enu).all(axis=1).mean() > 0.9)
    if not vel_measured:  # generic files without velocity: smoothed differences of positions
        src_t = rec.truth.t_s.to_numpy() if rec.truth is not None else tg
        src_p = _local_metres(rec.truth, *origin) if rec.truth is not None else p_g
        win = 2.0 if rec.truth is not None else 5.0  # s: noisy fixes need a longer baseline
        v_src = differenced_velocity(src_t, src_p[:, [1, 0, 2]], win)
        v_enu = np.stack([np.interp(tg, src_t, v_src[:, i]) for i in range(3)], -1)
    else:
        v_enu = np.where(np.isfinite(v_enu), v_enu, 0.0)
    return _GnssTrack(tg, p_g, v_enu, np.hypot(v_enu[:, 0], v_enu[:, 1]), vel_measured)


def _bridged_imu(imu, notes: list[str]):
    """IMU times, specific force and rate with time gaps bridged (a note says so): (t, f, w, gaps)."""
    t_imu = imu.t_s.to_numpy()
    f_b = imu[["f_x_mps2", "f_y_mps2", "f_z_mps2"]].to_numpy()
    w_b = imu[["w_x_radps", "w_y_radps", "w_z_radps"]].to_numpy()
    t_imu, f_b, w_b, gaps = bridge_gaps(t_imu, f_b, w_b)
    if gaps:
        longest = max(gaps, key=lambda gl: gl[1])
        notes.append(
            f"IMU: {len(gaps)} time gap(s) bridged by linear interpolation (longest {longest[1]:.2f} s at "
            f"t = {longest[0]:.2f} s); the INS coasts through them with raised process noise, so expect "
            "larger errors there"
            + ("; a gap this long is better cut out of the recording" if longest[1] > 10 else "")
        )
    return t_imu, f_b, w_b, gaps


@dataclass(frozen=True)
class _Start:
    """How the filters start: ``moving`` (in motion, at ``t_first``) or static (aligned before ``t_move``).

    ``t_begin``: first time with both GNSS and IMU; ``t_move``: when the vehicle starts moving.
    """

    moving: bool
    t_begin: float
    t_move: float
    t_first: float | None = None


def _choose_start(
    track: _GnssTrack, t_imu: Array, start: str, static_margin_s: float, notes: list[str]
) -> _Start:
    """Static alignment or an in-motion start (see :func:`prepare_drive`), and their times."""
    tg = track.t
    t_begin = max(tg[0], t_imu[0])
    try:
        t_move = motion_start_time(
            tg, track.v_enu, 0.3 if track.measured else 1.0, 1.0 if track.measured else 3.0
        )
    except NavlabError:  # never moves: align on the first seconds, filter the rest
        t_move = float(min(tg[-1], t_begin + MIN_STATIC_S + static_margin_s))
    static_ok = t_move - static_margin_s - t_begin >= MIN_STATIC_S
    if start == "static" and not static_ok:
        raise NavlabError(
            f"no static segment: the vehicle already moves at {t_move - t_begin:.1f} s after the start; "
            f"a static start needs {MIN_STATIC_S + static_margin_s:g} s at rest (start 'auto' or 'moving' "
            "initialises in motion)"
        )
    if not (start == "moving" or (start == "auto" and not static_ok)):
        return _Start(False, t_begin, t_move)
    v_min = HEADING_SPEED_MPS[0] if track.measured else HEADING_SPEED_MPS[1]
    cand = np.flatnonzero((track.speed >= v_min) & (tg >= t_imu[0] + 1.0))
    if not cand.size:
        raise NavlabError(
            f"the vehicle never moves faster than {v_min:g} m/s after the IMU starts, and there is no "
            "static segment to align on: navlab cannot initialise the INS on this recording"
        )
    t_first = float(tg[cand[0]])
    if t_first - t_begin > 1.5:
        notes.append(
            f"start: no static segment; the first {t_first - t_begin:.1f} s (until the vehicle first "
            f"moves faster than {v_min:g} m/s, so that the course gives the heading) are skipped"
        )
    return _Start(True, t_begin, t_move, t_first)


def _thin_epochs(t_fix: Array, rate_hz: float) -> Array:
    """The recorded epochs thinned to at most ``rate_hz`` per second (all of them for ``rate_hz`` ≤ 0)."""
    if not (rate_hz and rate_hz > 0):
        return t_fix
    keep, last = [], -np.inf
    for i, ti in enumerate(t_fix):
        if ti - last >= 1.0 / rate_hz - 1e-6:
            keep.append(i)
            last = ti
    return t_fix[keep]


def _fill_gnss_gaps(t_fix: Array, notes: list[str]) -> Array:
    """The epochs ``t_fix`` with epochs at the nominal interval inserted inside gaps (a note counts them)."""
    nominal = float(np.median(np.diff(t_fix)))
    parts = [t_fix[:1]]
    for a, b in itertools.pairwise(t_fix):
        if b - a > 1.5 * nominal:
            parts.append(np.arange(a + nominal, b - 0.5 * nominal, nominal))
        parts.append(np.array([b]))
    t = np.concatenate(parts)
    n_missing = len(t) - len(t_fix)
    if n_missing:
        notes.append(
            f"GNSS: {n_missing} epoch(s) without a fix inside gaps of the recording (nominal interval "
            f"{nominal:.3g} s); the filters predict through them"
        )
    return t


def _recorded_epochs(
    tg: Array,
    t_imu_end: float,
    st: _Start,
    rate_hz: float,
    epochs: int,
    static_margin_s: float,
    notes: list[str],
) -> tuple[Array, Array]:
    """Epoch times from the recorded GNSS epochs, and which of them have a fix: (t, fix_here)."""
    t_fix = _thin_epochs(tg, rate_hz)
    t_epoch0 = (
        st.t_first
        if st.moving
        else float(t_fix[max(0, np.searchsorted(t_fix, st.t_move - static_margin_s, side="right") - 1)])
    )
    t_fix = t_fix[t_fix >= t_epoch0 - 1e-9]
    t_fix = t_fix[t_fix <= t_imu_end]
    if len(t_fix) < 3:
        raise NavlabError("the drive is too short after its start: fewer than 3 GNSS epochs")
    t = _fill_gnss_gaps(t_fix, notes)
    if epochs:
        t = t[: int(epochs) + 1]
    return t, np.isin(np.round(t, 6), np.round(t_fix, 6))


def _grid_epochs(
    tg: Array, t_imu_end: float, st: _Start, rate_hz: float, epochs: int, static_margin_s: float
) -> tuple[Array, Array]:
    """Epoch times on a grid of ``rate_hz`` (every epoch aided): (t, fix_here)."""
    if st.moving:
        t_epoch0 = np.ceil(st.t_first * rate_hz - 1e-9) / rate_hz
    else:
        t_epoch0 = np.floor((st.t_move - static_margin_s) * rate_hz) / rate_hz
        t_epoch0 = max(t_epoch0, np.ceil(st.t_begin * rate_hz) / rate_hz)
    t_end = min(tg[-1], t_imu_end)
    K_avail = int(np.floor((t_end - t_epoch0) * rate_hz + 1e-9))
    if K_avail < 2:
        raise NavlabError("the drive is too short after its start for a 1 Hz filter")
    K = K_avail if not epochs else min(int(epochs), K_avail)
    t = t_epoch0 + np.arange(K + 1) / rate_hz
    return t, np.ones(len(t), bool)


def _epoch_times(
    tg: Array,
    t_imu_end: float,
    st: _Start,
    rate_hz: float,
    epochs: int,
    static_margin_s: float,
    recorded: bool,
    notes: list[str],
) -> tuple[Array, Array]:
    """The aiding epochs, recorded or on a grid, and which of them have a fix: (t, fix_here)."""
    if recorded:
        t, fix_here = _recorded_epochs(tg, t_imu_end, st, rate_hz, epochs, static_margin_s, notes)
    else:
        t, fix_here = _grid_epochs(tg, t_imu_end, st, rate_hz, epochs, static_margin_s)
    if len(t) - 1 < 2:
        raise NavlabError("the drive is too short after its start: give more GNSS epochs")
    return t, fix_here


def _gnss_at_epochs(g, tg: Array, p_g: Array, t: Array, fix_here: Array) -> tuple[Array, Array | None]:
    """The recording's fixes and their σ (None if not given for every fix) at the epochs."""
    dtg = float(np.median(np.diff(tg)))
    gnss_pos = interp_with_gaps(t, tg, p_g, max(1.5 * dtg, 1.0))
    gnss_pos[~fix_here] = np.nan
    sig_cols = g[["sigma_n_m", "sigma_e_m", "sigma_u_m"]].to_numpy()
    gnss_sigma = (
        interp_with_gaps(t, tg, sig_cols, max(1.5 * dtg, 1.0)) if np.isfinite(sig_cols).all() else None
    )
    return gnss_pos, gnss_sigma


def _truth_at_epochs(truth, t: Array, origin: tuple[float, float, float]) -> tuple[Array, Array]:
    """Reference positions N, E, U and velocities E, N, U at the epochs (NaN without a truth)."""
    if truth is None:
        return np.full((len(t), 3), np.nan), np.full((len(t), 3), np.nan)
    tt = truth.t_s.to_numpy()
    p_tt = _local_metres(truth, *origin)
    p_true = interp_with_gaps(t, tt, p_tt, max(1.5 * float(np.median(np.diff(tt))), 1.0))
    tcols = ("ve_mps", "vn_mps", "vu_mps")
    if all(c in truth.columns for c in tcols):
        # the receiver's velocities lag its positions (rtkx: 0.12 s, 0.1 m/s rms): the velocity
        # truth is read at t + lag so that rmse_vel and NEES measure the filters, not the lag
        vt = truth[list(tcols)].to_numpy()
        lag = velocity_lag_s(tt, p_tt, vt)
        t_v = np.minimum(t + lag, tt[-1])
        v_true = np.stack([np.interp(t_v, tt, vt[:, i], left=np.nan, right=np.nan) for i in range(3)], -1)
    else:
        vt = differenced_velocity(tt, p_tt[:, [1, 0, 2]], 2.0 * float(np.median(np.diff(tt))))
        v_true = np.stack([np.interp(t, tt, vt[:, i], left=np.nan, right=np.nan) for i in range(3)], -1)
    return p_true, v_true


def _align_in_motion(
    track: _GnssTrack, t0: float, t_imu: Array, f_b: Array, w_b: Array, origin, heading_deg, C_bv: Array
) -> AlignmentResult:
    """Alignment at ``t0`` while moving: heading from the course, tilt from f minus the GNSS acceleration."""
    tg, v_enu = track.t, track.v_enu
    heading = (
        course_heading(v_enu[np.searchsorted(tg, t0 - 1e-9)])
        if heading_deg is None
        else np.radians(heading_deg)
    )
    win = (t_imu >= t0 - 1.0) & (t_imu < t0)
    v1 = np.stack([np.interp(t0, tg, v_enu[:, i]) for i in range(3)])
    v0 = np.stack([np.interp(t0 - 1.0, tg, v_enu[:, i]) for i in range(3)])
    a_n = (v1 - v0) / 1.0 if track.measured else np.zeros(3)
    a_n[2] = 0.0  # a car: no sustained vertical acceleration
    return align_moving(f_b[win], w_b[win], a_n, origin[0], origin[2], float(heading), C_bv=C_bv)


def _align_at_rest(
    track: _GnssTrack, st: _Start, t0: float, t_imu, f_b, w_b, origin, heading_deg, C_bv, notes: list[str]
) -> tuple[AlignmentResult, bool]:
    """Static alignment on the samples before ``t0``; the heading from the course once moving.

    Returns the alignment and whether the heading is known (given, or from a course).
    """
    static = (t_imu < t0) & (t_imu >= t_imu[0])
    if static.sum() < 100:
        raise NavlabError(
            f"only {static.sum()} IMU samples before the vehicle moves (at {st.t_move:.1f} s); "
            "a static start needs the vehicle at rest for at least 2 s"
        )
    moving = np.flatnonzero((track.t > st.t_move) & (track.speed > (0.7 if track.measured else 2.0)))
    if heading_deg is not None:
        heading = np.radians(heading_deg)
    elif moving.size:
        heading = float(course_heading(track.v_enu[moving[0]]))
    else:
        heading = 0.0
        notes.append("start: the vehicle never moves, so its heading is unknown (taken as north, σ 30°)")
    al = align_static(f_b[static], w_b[static], origin[0], origin[2], heading, C_bv=C_bv)
    return al, heading_deg is not None or bool(moving.size)


def _block_vibration(t_imu: Array, w_b: Array, t: Array) -> Array:
    """Gyro vibration per aiding block from the raw samples: rms raw std × √dt [rad/√s], (K+1,)."""
    dt_raw = float(np.median(np.diff(t_imu)))
    edges = np.searchsorted(t_imu, t)
    vib_g = np.zeros(len(t))
    for k in range(1, len(t)):
        wk = w_b[edges[k - 1] : edges[k]]
        if len(wk) > 2:
            vib_g[k] = np.sqrt(np.mean(wk.var(axis=0)) * dt_raw)
    return vib_g


def _initial_in_motion(
    track: _GnssTrack, t0: float, gnss_pos: Array, gnss_sigma: Array | None, p_true: Array
) -> tuple[Array, Array]:
    """x0, P0 of an in-motion start: position from the first fix, velocity from the GNSS, biases unknown."""
    # position from the first fix (σ: the receiver's, else 3 m), velocity from the GNSS
    p0 = gnss_pos[0] if np.isfinite(gnss_pos[0]).all() else np.nan_to_num(p_true[0])
    sig_p = gnss_sigma[0] if gnss_sigma is not None and np.isfinite(gnss_sigma[0]).all() else np.full(3, 3.0)
    v0_ = np.stack([np.interp(t0, track.t, track.v_enu[:, i]) for i in range(3)])
    sig_v = 0.2 if track.measured else float(np.sqrt(2) * np.max(sig_p[:2]) / 5.0)
    sp0 = max(float(np.hypot(v0_[0], v0_[1])), 0.1)
    sig_head = np.degrees(np.hypot(np.arctan(sig_v / sp0), np.radians(2.0)))  # + side slip / mount yaw
    sig_tilt = 1.5 if track.measured else 6.0  # deg: σ_a/g of the acceleration assumption
    x0 = np.r_[np.zeros(3), v0_, p0, np.zeros(3), np.zeros(3)]
    P0 = np.diag(
        np.r_[
            np.radians([sig_tilt, sig_tilt, sig_head]) ** 2,
            [sig_v**2] * 3,
            sig_p**2,
            [np.radians(0.3) ** 2] * 3,  # gyro bias unknown: consumer MEMS turn-on bias ≲ 0.5 °/s
            [0.15**2] * 3,  # accelerometer bias unknown: ≈ 15 mg
        ]
    )
    return x0, P0


def _initial_at_rest(
    al: AlignmentResult, gnss_pos: Array, p_true: Array, vel_measured: bool, heading_known: bool
) -> tuple[Array, Array]:
    """x0, P0 of a static start: at rest, biases from the alignment."""
    p0 = gnss_pos[0] if np.isnan(p_true[0]).any() else p_true[0]
    # only the accelerometer bias along gravity is observable at rest: |f| − g along f
    ba0 = al.accel_norm_minus_gravity_mps2 * al.f_b_mean_mps2 / np.linalg.norm(al.f_b_mean_mps2)
    x0 = np.r_[np.zeros(3), np.zeros(3), p0, al.gyro_bias_radps, ba0]
    sig_head = 3.0 if vel_measured else 10.0  # deg: course from noisy fixes is rougher
    if not heading_known:
        sig_head = 30.0
    P0 = np.diag(
        np.r_[
            np.radians([0.5, 0.5, sig_head]) ** 2,
            [0.1**2] * 3,
            [1.0**2] * 3,
            [np.radians(0.05) ** 2] * 3,
            [0.1**2] * 3,
        ]
    )
    return x0, P0


def prepare_drive(
    rec: DriveRecording,
    rate_hz: float = 1.0,
    epochs: int = 0,
    static_margin_s: float = 2.0,
    heading_deg: float | None = None,
    imu_rate_hz: float = 20.0,
    *,
    recorded: bool = False,
    gnss_time_offset_s: float = 0.0,
    start: str = "auto",
    lever_arm_v_m=(0.0, 0.0, 0.0),
) -> DriveSetup:
    """Cut a drive into aiding epochs and initialise the INS (static alignment or in motion).

    Epochs: with ``recorded`` the GNSS epochs as recorded (at most ``rate_hz`` of them per second
    when ``rate_hz`` > 0; epochs without a fix are inserted at the nominal interval inside GNSS
    gaps); otherwise a grid of ``rate_hz`` (the aiding is made from the truth on it).

    Start (``start``): ``"auto"`` aligns on a static segment when the recording begins with at
    least :data:`MIN_STATIC_S` s at rest (plus ``static_margin_s``), else initialises in motion;
    ``"static"`` insists on a static segment, ``"moving"`` always initialises in motion. A static
    start takes roll and pitch from the mean static specific force, the gyro biases from the mean
    static rate and the heading from the GNSS course once moving (``heading_deg`` overrides it).
    An in-motion start begins at the first epoch where the vehicle moves faster than
    :data:`HEADING_SPEED_MPS`: position from the fix, velocity from the GNSS velocity (or
    differenced fixes), heading from the course, roll and pitch from the specific force minus the
    GNSS acceleration (:func:`navlab.ins.align.align_moving`), biases unknown — with a P0 that says
    so.

    ``gnss_time_offset_s`` is added to the GNSS time stamps (and not to the truth's);
    ``lever_arm_v_m`` is the antenna position relative to the IMU in the vehicle frame.
    IMU time gaps are bridged (:func:`bridge_gaps`) and reported in ``notes``.
    """
    if start not in ("auto", "static", "moving"):
        raise NavlabError(f"start must be 'auto', 'static' or 'moving', got {start!r}")
    notes: list[str] = []
    g = rec.gnss
    origin = (np.radians(g.lat_deg.iloc[0]), np.radians(g.lon_deg.iloc[0]), float(g.h_m.iloc[0]))
    track = _gnss_track(rec, gnss_time_offset_s, origin)
    t_imu, f_b, w_b, gaps = _bridged_imu(rec.imu, notes)
    st = _choose_start(track, t_imu, start, static_margin_s, notes)
    t, fix_here = _epoch_times(track.t, t_imu[-1], st, rate_hz, epochs, static_margin_s, recorded, notes)
    gnss_pos, gnss_sigma = _gnss_at_epochs(g, track.t, track.p, t, fix_here)
    p_true, v_true = _truth_at_epochs(rec.truth, t, origin)
    C_bv = np.asarray(rec.C_bv, float)
    if st.moving:
        al = _align_in_motion(track, t[0], t_imu, f_b, w_b, origin, heading_deg, C_bv)
        x0, P0 = _initial_in_motion(track, t[0], gnss_pos, gnss_sigma, p_true)
    else:
        al, heading_known = _align_at_rest(track, st, t[0], t_imu, f_b, w_b, origin, heading_deg, C_bv, notes)
        x0, P0 = _initial_at_rest(al, gnss_pos, p_true, track.measured, heading_known)
    vib_g = _block_vibration(t_imu, w_b, t)  # from the raw samples, before they are averaged
    t_imu, f_b, w_b = imu_on_epochs(t_imu, f_b, w_b, t, imu_rate_hz)
    return DriveSetup(
        t=t,
        lat0_rad=origin[0],
        lon0_rad=origin[1],
        h0_m=origin[2],
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
        C_bv=C_bv,
        vib_g=vib_g,
        gnss_sigma=gnss_sigma,
        start="moving" if st.moving else "static",
        lever_arm_v=np.asarray(lever_arm_v_m, float),
        gap_s=gap_time_per_block(t, gaps),
        notes=tuple(notes),
        gnss_time_offset_s=float(gnss_time_offset_s),
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


def _initial_ins_state(setup: DriveSetup, B: int) -> InsState:
    """B copies of the setup's initial solution (x0, C0) at epoch 0."""
    return init_state(
        *setup.from_local(np.broadcast_to(setup.x0[6:9], (B, 3))),
        setup.x0[3:6],
        np.broadcast_to(setup.C0, (B, 3, 3)),
        B=B,
        bias_g_radps=setup.x0[9:12],
        bias_a_mps2=setup.x0[12:15],
        t_s=setup.t[0],
    )


def _ekf_predict(
    setup: DriveSetup, k: int, s: InsState, P: Array, noise: ImuNoise, vib_g: float, gap_s: float
):
    """Mechanise through the block (t_{k−1}, t_k] and propagate P by the §8.0 error model, the
    IMU noise raised by the block's vibration and bridged gap: (state, P, mean ENU specific force).
    """
    sl = setup.imu_slice(k)
    s, blk = propagate_block(s, setup.t_imu[sl], setup.f_b[sl], setup.w_b[sl], t_end_s=setup.t[k])
    F, G = error_model_FG(s.lat_rad, s.h_m, s.v_enu_mps, blk.f_n_mean_mps2, s.C_bn)
    T = float(setup.t[k] - setup.t[k - 1])
    Phi = expm_batched(F * T)
    _, Qd = discretise(F, G, noise.Qc(vib_g) + gap_Qc(gap_s / T), T)
    return s, Phi @ P @ np.swapaxes(Phi, -1, -2) + Qd, blk.f_n_mean_mps2


def _position_update(setup: DriveSetup, s: InsState, P: Array, zk: Array, R: Array, lever_b: Array):
    """The error-state update with the antenna positions ``zk`` (B, 3) (NaN: no fix) and the
    correction fed back into the solutions (Joseph form): (state, P).
    """
    B = zk.shape[0]
    ok = np.isfinite(zk).all(axis=1)
    if not ok.any():
        return s, P
    u = (s.C_bn @ lever_b)[:, [1, 0, 2]]  # antenna offset C_bn l^b, N E U
    H = np.zeros((B, 3, 15))
    H[:, :, 6:9] = np.eye(3)
    H[:, :, 0:3] = skew(s.C_bn @ lever_b)[:, [1, 0, 2]]  # δ(C l) = (C l) × φ
    p_ins = setup.to_local(s.lat_rad, s.lon_rad, s.h_m) + u
    nu = np.where(ok[:, None], p_ins - np.nan_to_num(zk), 0.0)  # error-state innovation
    Ht = H.swapaxes(-1, -2)
    S = H @ P @ Ht + R
    Kg = np.linalg.solve(S, (P @ Ht).swapaxes(-1, -2)).swapaxes(-1, -2)
    Kg = Kg * ok[:, None, None]
    dx = (Kg @ nu[:, :, None])[:, :, 0]
    IKH = np.eye(15) - Kg @ H
    P = IKH @ P @ IKH.swapaxes(-1, -2) + Kg @ R @ Kg.swapaxes(-1, -2)
    return apply_correction(s, dx), P


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
    s = _initial_ins_state(setup, B)
    P = np.broadcast_to(setup.P0, (B, 15, 15)).copy()
    R = np.diag(np.broadcast_to(np.asarray(sigma_m, float) ** 2, (3,)))
    vib = setup.vib_g if setup.vib_g is not None else np.zeros(K + 1)
    gap = setup.gap_s if setup.gap_s is not None else np.zeros(K + 1)
    lever_b = setup.C_bv.T @ setup.lever_arm_v
    shapes = {"p": (3,), "v": (3,), "C": (3, 3), "bg": (3,), "ba": (3,), "fn": (3,), "Pd": (15,)}
    out = {k: np.full((B, K + 1, *shape), np.nan) for k, shape in shapes.items()}

    def record(k, s, P):
        out["p"][:, k] = setup.to_local(s.lat_rad, s.lon_rad, s.h_m)
        out["v"][:, k] = s.v_enu_mps
        out["C"][:, k] = s.C_bn
        out["bg"][:, k] = s.bias_g_radps
        out["ba"][:, k] = s.bias_a_mps2
        out["Pd"][:, k] = np.diagonal(P, axis1=-2, axis2=-1)

    record(0, s, P)
    for k in range(1, K + 1):
        s, P, out["fn"][:, k] = _ekf_predict(setup, k, s, P, noise, vib[k], gap[k])
        if z is not None:
            s, P = _position_update(setup, s, P, z[:, k], R, lever_b)
        P = 0.5 * (P + P.swapaxes(-1, -2))
        record(k, s, P)
    return ClosedLoopResult(out["p"], out["v"], out["C"], out["bg"], out["ba"], out["fn"], out["Pd"])


# ------------------------------------------------------------------------------ compiled model
# InsGnssModel's f, h and H are called for every filter at every epoch on a handful of runs, where
# numpy's per-call overhead (≈ 0.3 ms per f: the conversions around the mechanisation and the
# mechanisation's own set-up) is the whole cost. So they run compiled (navlab.jit), each written
# for one run as below; the numpy path (the methods' own code) is the reference the tests compare
# with (tests/unit/test_jit.py).


def _f_runs(x, out, C_prev, C_next, f_raw, w_raw, dts, origin):  # pragma: no cover - numba
    """out[r] = f(x[r]): total state → INS solution → strapdown over the block → total state.

    origin = (lat0, lon0, h0, R_Mh0, R_Nh0 cos lat0) of the local N, E, U metres; C_prev, C_next =
    C_ref at k−1 and k; f_raw, w_raw (N, 3) the block's raw samples, dts (N,) their holding times.
    """
    lat0, lon0, h0, RM, RNc = origin[0], origin[1], origin[2], origin[3], origin[4]
    nav = np.empty(3)
    v = np.empty(3)
    bg = np.empty(3)
    ba = np.empty(3)
    C = np.empty((3, 3))
    E = np.empty((1, 3, 3))
    phi = np.empty((1, 3))
    D = np.empty((1, 3, 3))
    sums = np.empty((3, 3))
    for r in range(x.shape[0]):
        # the INS solution of x: position from the local metres, C_bn = exp(−[a×]) C_ref,k−1
        nav[0] = lat0 + x[r, 6] / RM
        nav[1] = lon0 + x[r, 7] / RNc
        nav[2] = h0 + x[r, 8]
        for i in range(3):
            phi[0, i] = -x[r, i]
            v[i], bg[i], ba[i] = x[r, 3 + i], x[r, 9 + i], x[r, 12 + i]
        _rotvec_to_dcm_runs(phi, E)
        for i in range(3):
            for j in range(3):
                C[i, j] = E[0, i, 0] * C_prev[0, j] + E[0, i, 1] * C_prev[1, j] + E[0, i, 2] * C_prev[2, j]
        sums[:] = 0.0
        _mechanise_run(nav, v, C, f_raw, w_raw, ba, bg, dts, True, sums)
        # back to the total state: a = −log(C_bn C_ref,kᵀ), the local metres
        for i in range(3):
            for j in range(3):
                D[0, i, j] = C[i, 0] * C_next[j, 0] + C[i, 1] * C_next[j, 1] + C[i, 2] * C_next[j, 2]
        _dcm_to_rotvec_runs(D, phi)
        for i in range(3):
            out[r, i] = -phi[0, i]
            out[r, 3 + i], out[r, 9 + i], out[r, 12 + i] = v[i], bg[i], ba[i]
        out[r, 6] = (nav[0] - lat0) * RM
        out[r, 7] = (nav[1] - lon0) * RNc
        out[r, 8] = nav[2] - h0


def _hH_runs(x, C_ref, lever_b, C_bv, scale, nhc, h, H):  # pragma: no cover - numba
    """h(x[r]) into h (B, m) and, if H.shape[0] > 0, its Jacobian into H (B, m, 15).

    Rows N, E, U: p + C_bn l (lever arm l, C_bn = exp(−[a×]) C_ref), ∂/∂a = [u×] rows (N, E, U)
    with u = C_bn l; with ``nhc`` the vehicle's right and up velocity C_bv C_bnᵀ v, ∂/∂v = those
    rows of C_vn = C_bv C_bnᵀ, ∂/∂a = −C_vn [v×]. Every row divided by its scale.
    """
    E = np.empty((1, 3, 3))
    phi = np.empty((1, 3))
    C = np.empty((3, 3))
    Cvn = np.empty((3, 3))
    u = np.empty(3)
    jac = H.shape[0] > 0
    for r in range(x.shape[0]):
        for i in range(3):
            phi[0, i] = -x[r, i]
        _rotvec_to_dcm_runs(phi, E)
        for i in range(3):
            for j in range(3):
                C[i, j] = E[0, i, 0] * C_ref[0, j] + E[0, i, 1] * C_ref[1, j] + E[0, i, 2] * C_ref[2, j]
        for i in range(3):  # u = C_bn l (E, N, U)
            u[i] = C[i, 0] * lever_b[0] + C[i, 1] * lever_b[1] + C[i, 2] * lever_b[2]
        # positions N, E, U: p + (C_bn l) reordered from E, N, U
        h[r, 0] = (x[r, 6] + u[1]) / scale[0]
        h[r, 1] = (x[r, 7] + u[0]) / scale[1]
        h[r, 2] = (x[r, 8] + u[2]) / scale[2]
        if jac:
            for i in range(H.shape[1]):
                for j in range(15):
                    H[r, i, j] = 0.0
            for i in range(3):
                H[r, i, 6 + i] = 1.0 / scale[i]
            # [u×] in rows N, E, U (= rows 1, 0, 2 of [u×])
            H[r, 0, 0], H[r, 0, 2] = u[2] / scale[0], -u[0] / scale[0]
            H[r, 1, 1], H[r, 1, 2] = -u[2] / scale[1], u[1] / scale[1]
            H[r, 2, 0], H[r, 2, 1] = -u[1] / scale[2], u[0] / scale[2]
        if nhc:
            for i in range(3):  # C_vn = C_bv C_bnᵀ
                for j in range(3):
                    Cvn[i, j] = C_bv[i, 0] * C[j, 0] + C_bv[i, 1] * C[j, 1] + C_bv[i, 2] * C[j, 2]
            v0, v1, v2 = x[r, 3], x[r, 4], x[r, 5]
            for c in range(2):
                i = 2 * c  # right (0) and up (2) rows of the vehicle frame
                s = scale[3 + c]
                h[r, 3 + c] = (Cvn[i, 0] * v0 + Cvn[i, 1] * v1 + Cvn[i, 2] * v2) / s
                if jac:
                    for j in range(3):
                        H[r, 3 + c, 3 + j] = Cvn[i, j] / s
                    # −C_vn [v×]: row i times [v×] = (c1 v2 − c2 v1, c2 v0 − c0 v2, c0 v1 − c1 v0)
                    H[r, 3 + c, 0] = -(Cvn[i, 1] * v2 - Cvn[i, 2] * v1) / s
                    H[r, 3 + c, 1] = -(Cvn[i, 2] * v0 - Cvn[i, 0] * v2) / s
                    H[r, 3 + c, 2] = -(Cvn[i, 0] * v1 - Cvn[i, 1] * v0) / s


_F_RUNS = Kernel(_f_runs, uses=(_ROTVEC_TO_DCM, _DCM_TO_ROTVEC, _MECHANISE_RUN))
_HH_RUNS = Kernel(_hH_runs, uses=(_ROTVEC_TO_DCM,))


class InsGnssModel:
    """Total-state loosely coupled INS/GNSS model for navlab's filters (see the module docstring).

    Measurements: GNSS antenna positions z = p + C_bn l^b + v (N, E, U metres; l^b the lever arm
    of the setup, zero by default), R0 = diag(σ²), and, with ``nhc_sigma_mps`` > 0, the
    non-holonomic constraints of a car — zero velocity along the vehicle's right and up axes,
    z = 0 = [C_bv C_bnᵀ v]_{x,z} + v_nhc (two more channels).

    With ``gnss_sigma_k`` (K+1, 3) — the receiver's own per-epoch 1-σ — the GNSS channels are
    WHITENED: z/σ_k and h/σ_k, so every filter's nominal R0 = I for them although σ changes per
    epoch (the smartloc-berlin convention; an adaptive filter's R̂ is then a variance multiplier
    of the receiver's σ²). The caller divides z by :attr:`scale` (:meth:`whiten`).
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
        gnss_sigma_k: Array | None = None,
    ) -> None:
        self.setup = setup
        self.C_ref = carray(ref.C_bn[0])  # (K+1, 3, 3)
        self.nhc = nhc_sigma_mps > 0
        self.m = 5 if self.nhc else 3
        K = setup.K
        sig2 = np.asarray(sigma_m, float) ** 2 * np.ones(3)
        self.scale = np.ones((K + 1, self.m))
        if gnss_sigma_k is not None:
            sk = np.asarray(gnss_sigma_k, float)
            self.scale[:, :3] = np.where(np.isfinite(sk) & (sk > 0), sk, np.sqrt(sig2))
            sig2 = np.ones(3)
        self.whitened = gnss_sigma_k is not None
        self.R0 = np.diag(np.r_[sig2, [nhc_sigma_mps**2] * 2] if self.nhc else sig2)
        self.lever_b = setup.C_bv.T @ np.asarray(setup.lever_arm_v, float)
        self.has_lever = bool(np.any(self.lever_b != 0))
        self._H = np.zeros((3, 15))
        self._H[:, 6:9] = np.eye(3)
        R_Mh, R_Nh = radii(setup.lat0_rad, setup.h0_m)
        self._origin = np.array(
            [setup.lat0_rad, setup.lon0_rad, setup.h0_m, R_Mh, R_Nh * np.cos(setup.lat0_rad)], dtype=float
        )
        self._blocks: dict[int, tuple[Array, Array, Array]] = {}  # k -> IMU block (compiled f)
        self._C_bv = carray(setup.C_bv)
        self._lever = carray(self.lever_b)
        lat, _, h = setup.from_local(ref.p[0])
        self.Phi = np.empty((K + 1, 15, 15))
        self.Qd = np.empty((K + 1, 15, 15))
        self.Phi[0], self.Qd[0] = np.eye(15), np.zeros((15, 15))
        vib = setup.vib_g if setup.vib_g is not None else np.zeros(K + 1)
        gap = setup.gap_s if setup.gap_s is not None else np.zeros(K + 1)
        # the transitions k−1 → k, k = 1 … K, all at once (each exactly as it would be alone)
        T = np.diff(np.asarray(setup.t, dtype=float))
        F, G = error_model_FG(lat[:-1], h[:-1], ref.v[0, :-1], ref.f_n_mean[0, 1:], self.C_ref[:-1])
        _, Qd = discretise(F, G, noise.Qc(vib[1:]) + gap_Qc(gap[1:] / T), T)
        self.Phi[1:] = SIGN @ expm_batched(F * T[:, None, None]) @ SIGN
        self.Qd[1:] = SIGN @ Qd @ SIGN

    def whiten(self, z: Array) -> Array:
        """Measurements (B, K+1, m) in the model's units (divided by :attr:`scale`)."""
        return z / self.scale[None]

    def fixes(self, z: Array) -> Array:
        """The GNSS positions N, E, U [m] (B, K+1, 3) in measurements ``z`` of this model."""
        return z[..., :3] * self.scale[None, : z.shape[1], :3]

    def F(self, k: int) -> Array:
        return self.Phi[k]

    def Q(self, k: int) -> Array:
        return self.Qd[k]

    def f(self, x: Array, k: int) -> Array:
        st = self.setup
        kernel = _F_RUNS.get()
        if kernel is not None:  # compiled, one run at a time (the numpy path below is the reference)
            f_raw, w_raw, dts = self._block(k)
            out = np.empty((x.shape[0], 15))
            kernel(carray(x), out, self.C_ref[k - 1], self.C_ref[k], f_raw, w_raw, dts, self._origin)
            return out
        s = _state_from_total(st, x, self.C_ref[k - 1], float(st.t[k - 1]))
        sl = st.imu_slice(k)
        s, _ = propagate_block(s, st.t_imu[sl], st.f_b[sl], st.w_b[sl], t_end_s=float(st.t[k]))
        return _total_from_state(st, s, self.C_ref[k])

    def _block(self, k: int) -> tuple[Array, Array, Array]:
        """The IMU samples of (t_{k−1}, t_k] and their holding times, as propagate_block takes them."""
        blk = self._blocks.get(k)
        if blk is None:
            st = self.setup
            sl = st.imu_slice(k)
            t = st.t_imu[sl]
            t0, t1 = float(st.t[k - 1]), float(st.t[k])
            if t.size:
                starts = np.concatenate([[t0], np.maximum(t[1:], t0)])
                ends = np.minimum(np.concatenate([t[1:], [t1]]), t1)
                dts = ends - starts
            else:
                dts = np.zeros(0)
            blk = (carray(st.f_b[sl]), carray(st.w_b[sl]), carray(dts))
            self._blocks[k] = blk
        return blk

    def _C_bn(self, x: Array | None, k: int) -> Array:
        """(B, 3, 3) C_bn = exp(−[a×]) C_ref,k (the reference attitude when x is None)."""
        if x is None:
            return self.C_ref[k][None]
        return rotvec_to_dcm(-x[:, 0:3]) @ self.C_ref[k]

    def _C_vn(self, x: Array, k: int) -> Array:
        """(B, 3, 3) rotation ENU -> vehicle, C_bv C_bnᵀ."""
        return self.setup.C_bv @ np.swapaxes(self._C_bn(x, k), -1, -2)

    def _hH(self, x: Array, k: int, jacobian: bool) -> tuple[Array, Array] | None:
        """The compiled h and (if ``jacobian``) H; None without numba (then the numpy path)."""
        kernel = _HH_RUNS.get()
        if kernel is None:
            return None
        B = x.shape[0]
        h = np.empty((B, self.m))
        H = np.empty((B, self.m, 15) if jacobian else (0, self.m, 15))
        kernel(carray(x), self.C_ref[k], self._lever, self._C_bv, self.scale[k], self.nhc, h, H)
        return h, H

    def H(self, x: Array | None, k: int) -> Array:
        if not (self.nhc or self.has_lever or self.whitened):
            return self._H
        if x is not None and (hH := self._hH(x, k, True)) is not None:
            return hH[1]
        B = 1 if x is None else x.shape[0]
        H = np.zeros((B, self.m, 15))
        H[:, 0:3, 6:9] = np.eye(3)
        if self.has_lever:
            # C_bn l ≈ (I − [a×]) C_ref l = u + u × a with u = C_bn l → ∂/∂a = [u×] (rows N, E, U)
            u = self._C_bn(x, k) @ self.lever_b
            H[:, 0:3, 0:3] = skew(u)[:, [1, 0, 2]]
        if self.nhc:
            Cvn = self._C_vn(x, k)[:, [0, 2]]  # right and up rows
            v = np.zeros((B, 3)) if x is None else x[:, 3:6]
            H[:, 3:5, 3:6] = Cvn
            # C_bnᵀ v = C_refᵀ exp([a×]) v ≈ C_refᵀ (v + a × v) → ∂/∂a = −C_vn [v×]
            H[:, 3:5, 0:3] = -Cvn @ skew(v)
        H = H / self.scale[k][None, :, None]
        return H[0] if x is None else H

    def h(self, x: Array, k: int) -> Array:
        if (self.nhc or self.has_lever or self.whitened) and (hH := self._hH(x, k, False)) is not None:
            return hH[0]
        p = x[:, 6:9]
        if self.has_lever:
            p = p + (self._C_bn(x, k) @ self.lever_b)[:, [1, 0, 2]]
        if self.nhc:
            v_v = (self._C_vn(x, k) @ x[:, 3:6, None])[:, :, 0]
            p = np.concatenate([p, v_v[:, [0, 2]]], axis=1)
        return p / self.scale[k][None] if self.whitened else p


#: Process noise of the reference solution: looser than the filters' (it is aided at 5 cm and must
#: follow every real attitude change of the vibrating mount rather than smooth over it).
REFERENCE_NOISE = ImuNoise(
    arw_rad_rts=0.005, vrw_mps_rts=0.03, gyro_bias_rw=2e-5, accel_bias_rw=2e-3, vib_gyro_factor=0.0
)


def reference_solution(setup: DriveSetup, noise: ImuNoise = REFERENCE_NOISE) -> ClosedLoopResult:
    """Closed-loop EKF aided by the truth positions (σ = 5 cm): the linearisation reference.

    Without truth, the recording's own GNSS positions are used (σ: the receiver's median σ, else 2 m).
    """
    if np.isfinite(setup.p_true).all(axis=1).mean() > 0.5:
        return run_closed_loop(setup, setup.p_true[None], 0.05, noise)
    sig = 2.0
    if setup.gnss_sigma is not None and np.isfinite(setup.gnss_sigma).any():
        sig = np.maximum(np.nanmedian(setup.gnss_sigma, axis=0), 0.05)
    return run_closed_loop(setup, setup.gnss_pos[None], sig, noise)


__all__ = [
    "GAP_ACCEL_MPS2",
    "GAP_RATE_RADPS",
    "STATE_NAMES",
    "ClosedLoopResult",
    "DriveSetup",
    "ImuNoise",
    "InsGnssModel",
    "bridge_gaps",
    "gap_Qc",
    "prepare_drive",
    "reference_solution",
    "run_closed_loop",
    "static_noise_densities",
    "velocity_lag_s",
]
