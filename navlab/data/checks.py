"""Plain-words checks of a user's recording before a run, and of the result after it.

Before a run (:func:`check_drive`): sample rate and gaps, gravity magnitude and sign on the
vehicle's z axis, the IMU's tilt in the vehicle frame, gyro units and sign (the IMU's heading
change against the GNSS course change), a GNSS time-offset hint (the lag that best aligns the GNSS
course with the IMU's heading, :func:`time_offset_hint`, reported with its uncertainty and only
when the drive's turns make it observable), and outliers in the raw fixes (:func:`fix_outliers`).

After a run (:func:`trust_check`): when every filter's position error exceeds the raw GNSS's own
error by :data:`TRUST_FACTOR` (against the truth, or against the GNSS fixes themselves when there
is no truth — labelled so), the result cannot be trusted, and the likely causes are listed.

Every function returns :class:`Finding` s — pure data; the CLI prints them to stderr, the Real
data page shows them as notes and warnings.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from navlab.ins.align import course_heading
from navlab.linalg import Array

if TYPE_CHECKING:
    from navlab.data.loaders import DriveRecording
    from navlab.experiment import Results
    from navlab.ins.lc import DriveSetup

#: The result cannot be trusted when the BEST filter's position RMSE exceeds the raw GNSS's own
#: RMSE by this factor (and by :data:`TRUST_MARGIN_M`): an INS/GNSS filter, or a filter over a
#: motion model, is fed the GNSS and should never be much worse than it.
TRUST_FACTOR = 1.5
TRUST_MARGIN_M = 0.25
G_MPS2 = 9.80665


class Finding(NamedTuple):
    """One message: ``level`` is "note" (information) or "warning" (something is wrong);
    ``causes`` lists what to check (the trust check's likely causes).
    """

    level: str
    text: str
    causes: tuple[str, ...] = ()

    def __str__(self) -> str:
        tail = (
            (" Likely causes: " + "; ".join(f"({i + 1}) {c}" for i, c in enumerate(self.causes)))
            if self.causes
            else ""
        )
        return f"{self.level}: {self.text}{tail}"


# ----------------------------------------------------------------------------- before a run


def heading_change_slope(
    t_g: Array, v_enu: Array, t_imu: Array, w_up: Array, window_s: float, min_speed_mps: float = 4.0
) -> tuple[float, float, int]:
    """Slope of the IMU's heading change against the GNSS course change over ``window_s`` windows.

    The IMU turns counter-clockwise positive, the course clockwise: a right unit/sign gives +1,
    deg/s instead of rad/s ≈ 57.3, a reversed z axis −1. The GNSS course change (noisy) is
    regressed on the IMU's (precise), and the slope inverted, so that the GNSS noise does not bias
    it towards 0. Returns (slope, correlation, number of windows).
    """
    t0 = np.arange(t_g[0], t_g[-1] - window_s, window_s)
    if t0.size < 5:
        return float("nan"), 0.0, 0
    sp = np.hypot(v_enu[:, 0], v_enu[:, 1])
    crs = np.unwrap(course_heading(v_enu))
    c0, c1 = np.interp(t0, t_g, crs), np.interp(t0 + window_s, t_g, crs)
    s0, s1 = np.interp(t0, t_g, sp), np.interp(t0 + window_s, t_g, sp)
    moving = (np.minimum(s0, s1) > min_speed_mps) & (
        np.array([sp[(t_g >= a) & (t_g <= a + window_s)].min(initial=np.inf) for a in t0]) > min_speed_mps
    )
    # ∫ w dt over each window from the cumulative integral of the IMU rate
    dt = np.diff(t_imu, append=t_imu[-1])
    cum = np.r_[0.0, np.cumsum(w_up * dt)][:-1]
    d_imu = np.interp(t0 + window_s, t_imu, cum) - np.interp(t0, t_imu, cum)
    d_gnss = -(c1 - c0)  # clockwise course → counter-clockwise heading change
    d_imu, d_gnss = d_imu[moving], d_gnss[moving]
    if d_gnss.size < 5:
        return float("nan"), 0.0, int(d_gnss.size)
    inv = float(d_imu @ d_gnss / max(d_imu @ d_imu, 1e-300))
    r = float(np.corrcoef(d_imu, d_gnss)[0, 1]) if np.std(d_imu) > 0 and np.std(d_gnss) > 0 else 0.0
    return (1.0 / inv if inv != 0 else float("inf")), r, int(d_gnss.size)


class OffsetEstimate(NamedTuple):
    """A GNSS time offset estimate: ``offset_s`` (to ADD to the GNSS time stamps), its standard
    error ``se_s`` (inf when not estimable), the fixes used ``n`` and the rms yaw rate ``turn_radps``
    that carries the information (after each piece's own heading offset and drift).
    """

    offset_s: float
    se_s: float
    n: int
    turn_radps: float

    @property
    def observable(self) -> bool:
        """The drive excites the offset: it is known to :data:`OFFSET_MAX_SE_S` or better."""
        return bool(np.isfinite(self.offset_s) and self.se_s <= OFFSET_MAX_SE_S)


#: A GNSS time offset is reported only when its standard error is at most this [s] (95 %: ± 0.05 s,
#: ≈ ± 1 m along the track at 20 m/s, below an ordinary receiver's σ): a drive that hardly turns
#: cannot tell an offset from the course noise (issue 24).
OFFSET_MAX_SE_S = 0.025
#: Pieces of the drive with their own heading offset and gyro drift [s].
OFFSET_PIECE_S = 10.0


def _moving_pieces(t: Array, moving: Array, piece_s: float) -> Array:
    """A piece number per fix (−1: not used): contiguous moving stretches (no gap longer than three
    fix intervals, or 1 s) cut into ``piece_s`` pieces.
    """
    piece = np.full(len(t), -1)
    gap = max(1.0, 3.0 * float(np.median(np.diff(t)))) if len(t) > 1 else 1.0
    n, start, prev = -1, None, None
    for i in np.flatnonzero(moving):
        if prev is None or i != prev + 1 or t[i] - t[prev] > gap or t[i] - start > piece_s:
            n, start = n + 1, t[i]
        piece[i], prev = n, i
    return piece


def _grid_min(lags: Array, sse: Array) -> float:
    """The lag minimising ``sse`` on the grid, refined by a parabola through its neighbours."""
    i = int(np.argmin(sse))
    L = float(lags[i])
    if 0 < i < len(lags) - 1:
        den = sse[i - 1] - 2 * sse[i] + sse[i + 1]
        if den > 0:
            L += (lags[1] - lags[0]) * 0.5 * (sse[i - 1] - sse[i + 1]) / den
    return L


def time_offset_hint(
    t_g: Array, v_enu: Array, t_imu: Array, w_up: Array, max_lag_s: float = 1.0, min_speed_mps: float = 4.0
) -> OffsetEstimate:
    """The GNSS time offset L [s] that best aligns the GNSS course with the IMU's heading, with its
    standard error.

    Model: −course(t_i) = ψ_IMU(t_i + L) + a_j + b_j t_i + e_i on moving fixes (speed >
    ``min_speed_mps``), ψ_IMU the integrated yaw rate, (a_j, b_j) a heading offset and a gyro
    drift per piece of :data:`OFFSET_PIECE_S` s, e_i the course noise (weights ∝ speed², since
    course noise ∝ σ_v / speed). L minimises the weighted squared residuals on a 10 ms grid
    (refined by a parabola). Its standard error is the linearised one,
    σ̂² / Σ w_i (∂r_i/∂L)², ∂r/∂L = the yaw rate with each piece's mean and trend removed, inflated
    by (1 + ρ)/(1 − ρ) for the residuals' lag-1 correlation ρ. Only turns carry information: on a
    straight road the yaw rate is ≈ 0 and the error is large (``se_s`` → inf). The returned L is
    the value to ADD to the GNSS time stamps; shifting the GNSS stamps by δ shifts it by −δ.
    """
    nan = OffsetEstimate(float("nan"), float("inf"), 0, 0.0)
    t_g, t_imu, w_up = (np.asarray(a, float) for a in (t_g, t_imu, w_up))
    sp = np.hypot(v_enu[:, 0], v_enu[:, 1])
    inside = (t_g - max_lag_s >= t_imu[0]) & (t_g + max_lag_s <= t_imu[-1])
    piece = _moving_pieces(t_g, (sp > min_speed_mps) & inside, OFFSET_PIECE_S)
    counts = np.bincount(piece[piece >= 0]) if (piece >= 0).any() else np.zeros(0, int)
    piece[(piece >= 0) & np.isin(piece, np.flatnonzero(counts < 5))] = -1
    use = piece >= 0
    if use.sum() < 20:
        return nan
    _, piece = np.unique(piece[use], return_inverse=True)
    t, v, wt = t_g[use], v_enu[use], sp[use] ** 2
    wt = wt / wt.mean()
    psi_g = np.empty(len(t))
    for j in range(piece.max() + 1):  # unwrap inside each piece
        m = piece == j
        psi_g[m] = -np.unwrap(course_heading(v[m]))  # the piece's offset absorbs 2π
    # nuisance columns: a per-piece offset and drift (time relative to the piece's mean)
    A = np.zeros((len(t), 2 * (piece.max() + 1)))
    for j in range(piece.max() + 1):
        m = piece == j
        A[m, 2 * j] = 1.0
        A[m, 2 * j + 1] = t[m] - t[m].mean()
    sw = np.sqrt(wt)
    Q, _ = np.linalg.qr(A * sw[:, None])

    def resid(y):  # weighted residual of y after the nuisance columns
        yw = y * sw
        return yw - Q @ (Q.T @ yw)

    dt = np.diff(t_imu, append=t_imu[-1])
    cum = np.r_[0.0, np.cumsum(w_up * dt)][:-1]
    lags = np.arange(-max_lag_s, max_lag_s + 1e-9, 0.01)
    n_p = int(piece.max()) + 1
    # squared residuals per piece and lag (the nuisance is per piece, so pieces are separable)
    sse_p = np.stack(
        [np.bincount(piece, resid(psi_g - np.interp(t + L, t_imu, cum)) ** 2, n_p) for L in lags], 1
    )
    L = _grid_min(lags, sse_p.sum(axis=0))
    r = resid(psi_g - np.interp(t + L, t_imu, cum))
    J = resid(np.interp(t + L, t_imu, w_up))  # ∂r/∂L (weighted, nuisance removed)
    dof = max(len(t) - A.shape[1] - 1, 1)
    s2 = float(r @ r) / dof
    rho = float(np.clip(np.sum(r[1:] * r[:-1]) / max(float(r @ r), 1e-300), 0.0, 0.9))
    info = float(J @ J)
    se = float(np.sqrt(s2 / info * (1 + rho) / (1 - rho))) if info > 0 else float("inf")
    if n_p >= 4:  # delete-one-piece jackknife: the spread between pieces (model error) counts too
        Lj = np.array([_grid_min(lags, sse_p.sum(axis=0) - sse_p[j]) for j in range(n_p)])
        se = max(se, float(np.sqrt((n_p - 1) / n_p * np.sum((Lj - Lj.mean()) ** 2))))
    return OffsetEstimate(L, se, len(t), float(np.sqrt(info / len(t))))


def _rate_findings(ti: Array, tg: Array) -> list[Finding]:
    """The IMU's and the GNSS's sample counts, rates and spans; a warning for a slow IMU."""
    dti = float(np.median(np.diff(ti)))
    dtg = float(np.median(np.diff(tg)))
    out = [
        Finding(
            "note",
            f"IMU: {len(ti)} samples at {1 / dti:.4g} Hz over {ti[-1] - ti[0]:.1f} s; GNSS: {len(tg)} "
            f"fixes at {1 / dtg:.3g} Hz over {tg[-1] - tg[0]:.1f} s",
        )
    ]
    if 1 / dti < 20:
        out.append(
            Finding("warning", f"IMU rate {1 / dti:.3g} Hz is low for a strapdown INS (≥ 50 Hz usual)")
        )
    return out


def _level_finding(f_v: Array, mag: float, what: str) -> Finding:
    """Gravity on +z: a note with the vehicle's pitch and roll, a warning when they exceed 8°."""
    pitch = float(np.degrees(np.arcsin(np.clip(f_v[1] / mag, -1, 1))))
    roll = float(np.degrees(np.arctan2(-f_v[0], f_v[2])))
    if max(abs(pitch), abs(roll)) > 8.0:
        return Finding(
            "warning",
            f"the IMU looks tilted in the vehicle frame (pitch {pitch:+.1f}°, roll {roll:+.1f}° {what}); "
            "a car is level within a few degrees on average: set mount_pitch_deg / mount_roll_deg",
        )
    return Finding(
        "note",
        f"gravity: {mag:.3f} m/s² on +z {what} (vehicle pitch {pitch:+.1f}°, roll {roll:+.1f}°)",
    )


def _gravity_findings(imu, ti: Array, setup: DriveSetup) -> list[Finding]:
    """Gravity in the vehicle frame (the mean specific force at rest, or averaged over the drive):
    its magnitude (accelerometer scale), its axis and sign (mounting), the tilt.
    """
    out: list[Finding] = []
    f_b = imu[["f_x_mps2", "f_y_mps2", "f_z_mps2"]].to_numpy()
    static = ti < setup.t[0] if setup.start == "static" else np.ones(len(ti), bool)
    f_v = setup.C_bv @ f_b[static].mean(axis=0)
    mag = float(np.linalg.norm(f_v))
    what = "at rest" if setup.start == "static" else "averaged over the drive"
    if not 9.3 < mag < 10.3:
        out.append(
            Finding(
                "warning",
                f"gravity: the mean specific force {what} is {mag:.3g} m/s², not ≈ 9.81: the "
                "accelerometer scale is wrong (f_*_mps2 must be m/s²: multiply g by 9.80665)",
            )
        )
    axis = int(np.argmax(np.abs(f_v)))
    if axis != 2:
        out.append(
            Finding(
                "warning",
                f"gravity lies on the vehicle's {'xy'[axis]} axis ({f_v[axis]:+.2f} m/s²), not on z: the IMU "
                "axes are not the vehicle's (x right, y forward, z up); give the mounting rotation "
                "(mount_roll_deg, mount_pitch_deg, mount_yaw_deg) or rotate the columns",
            )
        )
    elif f_v[2] < 0:
        out.append(
            Finding(
                "warning",
                f"gravity reads {f_v[2]:+.2f} m/s² on z: the IMU's z axis points DOWN (a NED/FRD IMU); give "
                "z up (negate y and z) or set mount_roll_deg = 180",
            )
        )
    else:
        out.append(_level_finding(f_v, mag, what))
    return out


def _gnss_positions(g, setup: DriveSetup) -> Array:
    """The fixes in the setup's local N, E, U [m]."""
    return setup.to_local(
        np.radians(g.lat_deg.to_numpy()), np.radians(g.lon_deg.to_numpy()), g.h_m.to_numpy()
    )


def _gnss_velocity(g, tg: Array, setup: DriveSetup) -> tuple[Array, bool]:
    """ENU velocities of the fixes (the receiver's, else differenced fixes) and whether measured."""
    from navlab.ins.lc import differenced_velocity

    v_cols = g[["ve_mps", "vn_mps", "vu_mps"]].to_numpy()
    if np.isfinite(v_cols).all():
        return v_cols, True
    return differenced_velocity(tg, _gnss_positions(g, setup)[:, [1, 0, 2]], 5.0), False


def _gyro_finding(slope: float, r: float, n: int) -> Finding:
    """Gyro units and sign from the slope of the IMU's heading change against the GNSS course change."""
    if n < 5 or abs(r) < 0.5:
        return Finding(
            "note",
            "gyro units/sign: not checked (the vehicle hardly turns while moving, or its GNSS course "
            "is too noisy to compare with)",
        )
    if abs(slope - 1) < 0.25:
        return Finding("note", f"gyro: the IMU's heading change follows the GNSS course (slope {slope:.2f})")
    if abs(slope + 1) < 0.25:
        return Finding(
            "warning",
            "gyro sign: the IMU turns the other way than the GNSS course (slope "
            f"{slope:.2f}): its z axis points down or w_z_radps is clockwise-positive; negate it",
        )
    if abs(slope / np.degrees(1.0) - 1) < 0.25:
        return Finding(
            "warning",
            f"gyro units: the IMU's heading change is {slope:.0f}× the GNSS course change: the rates are "
            "in deg/s; give w_*_radps in rad/s (multiply deg/s by 0.0174533)",
        )
    return Finding(
        "warning",
        f"gyro: the IMU's heading change is {slope:.2f}× the GNSS course change (expected 1): check "
        "the gyro units, the axes (mounting) and that both files use one time base",
    )


def _time_offset_findings(
    g, setup: DriveSetup, tg: Array, v_enu: Array, ti: Array, w_up: Array
) -> list[Finding]:
    """The GNSS time offset that best aligns the course with the heading (receiver velocities only),
    reported with its uncertainty, and only when the drive's turns make it observable.
    """
    from navlab.ins.lc import velocity_lag_s

    offset = float(getattr(setup, "gnss_time_offset_s", 0.0))
    est = time_offset_hint(tg + offset, v_enu, ti, w_up)
    if not est.observable:
        known = f" (it would be known to ±{2 * est.se_s:.2f} s only)" if np.isfinite(est.se_s) else ""
        return [
            Finding(
                "note",
                "GNSS time offset: not observable on this drive — the vehicle turns too little while "
                f"moving to tell a time offset from the course noise{known}; gnss_time_offset_s stays "
                f"{offset:+.2f} s",
            )
        ]
    # a receiver's velocities may lag its positions (RTKLIB: ≈ 0.12 s); measurable only on
    # precise fixes (σ < 0.2 m), else the velocities are taken as on the positions' time base
    sig = g[["sigma_n_m", "sigma_e_m"]].to_numpy()
    d_v = 0.0
    if np.isfinite(sig).all() and np.nanmedian(sig) < 0.2:
        d_v = velocity_lag_s(tg, _gnss_positions(g, setup), v_enu)
    total = offset + est.offset_s + d_v
    # a warning only when the offset is both significant and large enough to matter: the fixes
    # then sit further along the track (|L| × the median speed) than the receiver's σ
    moving = np.hypot(v_enu[:, 0], v_enu[:, 1]) > 4.0
    speed = float(np.median(np.hypot(v_enu[moving, 0], v_enu[moving, 1]))) if moving.any() else 0.0
    sig_h = float(np.nanmedian(sig)) if np.isfinite(sig).any() else 1.0
    shift = abs(est.offset_s + d_v)
    significant = shift > 2.0 * est.se_s and shift * speed > sig_h
    text = (
        f"GNSS time offset: the GNSS course best matches the IMU's heading with gnss_time_offset_s "
        f"≈ {total:+.2f} ± {2 * est.se_s:.2f} s (95 %; now {offset:+.2f} s; from {est.n} moving fixes"
        + (f"; the receiver's velocities lag its positions by {d_v:.2f} s" if d_v else "")
        + ")"
        + ("" if significant else f": within the uncertainty or < {sig_h:.2g} m along the track, leave it")
    )
    return [Finding("warning" if significant else "note", text)]


#: A raw fix is an outlier for the pre-run check when it lies more than this many of its own σ
#: (horizontal, or vertical) from what its neighbours predict.
OUTLIER_SIGMAS = 5.0


def _theil_sen(t: Array, y: Array, t0: float) -> Array:
    """Robust line through (t, y (n, d)) evaluated at t0: median pairwise slope, median intercept."""
    i, j = np.triu_indices(len(t), 1)
    dt = t[j] - t[i]
    ok = dt > 1e-9
    slope = np.median((y[j[ok]] - y[i[ok]]) / dt[ok, None], axis=0) if ok.any() else np.zeros(y.shape[1])
    return np.median(y - slope * (t - t0)[:, None], axis=0)


def fix_outliers(t: Array, p: Array, v_enu: Array | None, sigma: Array) -> Array:
    """Which fixes (N,) lie far from their neighbours: > :data:`OUTLIER_SIGMAS` × σ from the median of
    the neighbours' predictions p_j + v̄ (t_i − t_j) (v̄ the mean of the two fixes' velocities) within
    ± max(1 s, 2 fix intervals), or — without velocities — from a robust (Theil–Sen) line through
    them. ``sigma`` (N, 3): the fixes' σ N, E, U. No truth is involved.
    """
    t = np.asarray(t, float)
    n = len(t)
    out = np.zeros(n, bool)
    if n < 5:
        return out
    half = max(1.0, 2.0 * float(np.median(np.diff(t))))
    lo, hi = np.searchsorted(t, t - half), np.searchsorted(t, t + half, side="right")
    v_ne = None if v_enu is None else np.asarray(v_enu, float)[:, [1, 0, 2]]
    for i in range(n):
        nb = np.r_[lo[i] : i, i + 1 : hi[i]]
        if nb.size < 2:
            continue
        if v_ne is not None:
            pred = np.median(p[nb] + 0.5 * (v_ne[nb] + v_ne[i]) * (t[i] - t[nb])[:, None], axis=0)
        else:
            pred = _theil_sen(t[nb], p[nb], t[i])
        r = (p[i] - pred) / sigma[i]
        out[i] = np.hypot(r[0], r[1]) > OUTLIER_SIGMAS or abs(r[2]) > OUTLIER_SIGMAS
    return out


def _outlier_findings(
    g, setup: DriveSetup, v_enu: Array | None, sigma_m: float
) -> tuple[list[Finding], Array]:
    """The outlier check of the raw fixes: findings and the flag per recorded fix."""
    tg = g.t_s.to_numpy()
    sig = g[["sigma_n_m", "sigma_e_m", "sigma_u_m"]].to_numpy()
    sig = np.where(np.isfinite(sig) & (sig > 0), sig, sigma_m)
    flags = fix_outliers(tg, _gnss_positions(g, setup), v_enu, sig)
    k = int(flags.sum())
    if not k:
        return [
            Finding("note", f"outliers: no raw fix lies more than {OUTLIER_SIGMAS:g} σ from its neighbours")
        ], flags
    level = "warning" if k > 0.01 * len(tg) else "note"
    return [
        Finding(
            level,
            f"outliers: {k} of {len(tg)} raw fixes ({100 * k / len(tg):.1f} %) lie more than "
            f"{OUTLIER_SIGMAS:g} σ from what their neighbours predict: prefer a robust filter "
            "(χ²-gated KF, Huber KF, HAKF, IRAKF); the check after the run compares the filters "
            "with the other fixes",
        )
    ], flags


def check_drive(rec: DriveRecording, setup: DriveSetup, sigma_m: float = 3.0) -> list[Finding]:
    """Plain-words checks of a drive (generic CSV) before the filters run; see the module doc."""
    imu, g = rec.imu, rec.gnss
    ti = imu.t_s.to_numpy()
    tg = g.t_s.to_numpy()
    out = _rate_findings(ti, tg) + _gravity_findings(imu, ti, setup)
    # gyro units and sign: heading change of the IMU against the GNSS course change
    v_enu, measured = _gnss_velocity(g, tg, setup)
    w_up = imu[["w_x_radps", "w_y_radps", "w_z_radps"]].to_numpy() @ setup.C_bv[2]
    out.append(_gyro_finding(*heading_change_slope(tg, v_enu, ti, w_up, 2.0 if measured else 5.0)))
    if measured:  # the GNSS time offset hint needs the receiver's velocities
        out += _time_offset_findings(g, setup, tg, v_enu, ti, w_up)
    else:
        out.append(
            Finding("note", "GNSS time offset: no hint (gnss.csv has no vn_mps, ve_mps, vu_mps columns)")
        )
    found, _ = _outlier_findings(g, setup, v_enu if measured else None, sigma_m)
    return out + found


def raw_outlier_epochs(rec: DriveRecording, setup: DriveSetup, sigma_m: float) -> Array:
    """(K+1,) the epochs whose recorded fix the pre-run outlier check flags (:func:`fix_outliers`)."""
    g = rec.gnss
    tg = g.t_s.to_numpy()
    v_enu, measured = _gnss_velocity(g, tg, setup)
    _, flags = _outlier_findings(g, setup, v_enu if measured else None, sigma_m)
    t_fix = tg + float(getattr(setup, "gnss_time_offset_s", 0.0))
    return np.isin(np.round(setup.t, 6), np.round(t_fix[flags], 6))


def aiding_note(scenario: Any, setup: DriveSetup, rx_sigma: Array | None) -> str:
    """What the filters are fed, in plain words (printed by the CLI, shown on the page)."""
    p = scenario.params
    if not getattr(scenario, "own", False):
        return (
            f"GNSS aiding: made from the RTK truth at 1 Hz with synthetic noise σ = {p.sigma_m:g} m per axis "
            "and the chosen outlier model (this recording has no second receiver)"
            if p.add_noise
            else "GNSS aiding: the RTK truth at 1 Hz without noise (add_noise off)"
        )
    dt = np.diff(setup.t)
    rate = 1.0 / float(np.median(dt)) if dt.size else float("nan")
    sig = (
        f"the receiver's σ per epoch (median {np.nanmedian(rx_sigma[:, 0]):.3g} m north)"
        if rx_sigma is not None
        else f"σ = {p.sigma_m:g} m per axis (sigma_m"
        + ("; the receiver's σ ignored)" if setup.gnss_sigma is not None else "; no sigma_* columns)")
    )
    extra = f"with synthetic noise σ = {p.sigma_m:g} m added (add_noise)" if p.add_noise else ""
    return (
        f"GNSS: the recorded fixes {'as recorded' if not p.add_noise else extra}"
        f"{' (no synthetic noise or outliers unless a contamination is set)' if not p.add_noise else ''}, "
        f"{rate:.3g} Hz, R from {sig}; start: {setup.start}"
    )


# ----------------------------------------------------------------------------- after a run

_DRIVE_CAUSES = (
    "the IMU axes: gravity must read +9.8 m/s² on the vehicle's z (up) axis, x right, y forward — "
    "otherwise give the mounting rotation (mount_roll_deg, mount_pitch_deg, mount_yaw_deg)",
    "gyro units or sign: w_*_radps in rad/s, counter-clockwise positive (right-hand rule)",
    "the GNSS time base: GNSS and IMU must share t_s; a receiver latency is set with gnss_time_offset_s "
    "(see the hint)",
    "the GNSS σ: the receiver's sigma_* (use_receiver_sigmas) or sigma_m far from the fixes' real error",
    "the lever arm (lever_right_m, lever_forward_m, lever_up_m) when the antenna is far from the IMU",
    "an IMU much worse than consumer MEMS: raise arw_rad_rts / vrw_mps_rts",
)
_PR_CAUSES = (
    "the pseudorange variance model (variance_model, cn0_a) far from the real errors",
    "satellite positions not at transmit time or not ECEF (the Sagnac correction assumes transmit time)",
    "satellite-system codes: each system gets its own clock (1 GPS, 2 SBAS, 4 GLONASS, 8 Galileo, "
    "16 QZSS, 32 BeiDou)",
    "the odometry: speed in m/s, yaw rate in rad/s counter-clockwise positive, on the ranges' time base",
    "the truth: ECEF metres (or lat/lon/ellipsoidal height) of the same antenna, on the same time base",
)


def _pos_rms(e: Array) -> float:
    """RMS of 3-D error vectors (..., 3), NaN entries left out."""
    sq = np.sum(e**2, axis=-1)
    sq = sq[np.isfinite(sq)]
    return float(np.sqrt(np.mean(sq))) if sq.size else float("nan")


def _filter_rms(res: Results, idx: list[int], ref: Array) -> dict[str, float]:
    """Each filter's 3-D position RMS over the judged window against ``ref`` (the truth or the
    fixes, (B, K+1, 3)), over its runs that did not diverge (inf if every run diverged); not the
    per-epoch fix ``wls``, which is a raw baseline here, not a filter.
    """
    W = res.data.window
    errs = {}
    for key, fr in res.runs.items():
        ok = ~fr.diverged
        if key != "wls":
            errs[key] = _pos_rms((fr.x[..., idx] - ref)[ok][:, W]) if ok.any() else np.inf
    return errs


def _raw_fixes(d: Any, fixes: Array) -> tuple[float, str, str, Array | None, str]:
    """The raw GNSS fixes' 3-D RMS, its basis, its label, the truth it is judged against (None: no
    truth, the fixes' stated σ stands in) and what is said after the figure (the outlying fixes
    left out of it).
    """
    W = d.window
    p_ant = d.extras.get("p_true_antenna")
    if not (d.has_truth and p_ant is not None):
        sig = np.asarray(d.extras.get("fix_sigma_m"), float)
        raw = float(np.sqrt(np.nanmean(np.sum(sig[W] ** 2, axis=-1))))
        basis = "against the GNSS fixes themselves (no truth): the raw figure is the GNSS's stated σ"
        return raw, basis, "the raw GNSS fixes", None, ""
    e_raw = fixes - p_ant[None]
    # outlying fixes (flagged before the run, or injected) are left out of the raw figure: with
    # them in it, a filter worse than the clean fixes could still look better than "raw"
    bad = np.zeros(e_raw.shape[:2], bool) | np.asarray(d.extras.get("raw_outliers", False))
    if getattr(d, "outlier_mask", None) is not None:
        bad |= np.asarray(d.outlier_mask)[..., :3].any(axis=-1)
    raw = _pos_rms(np.where(bad[..., None], np.nan, e_raw)[:, W])
    n_bad = int(bad[:, W].sum())
    aside = f" ({n_bad} outlying fixes left out; {_pos_rms(e_raw[:, W]):.3g} m with them)" if n_bad else ""
    return raw, "against the truth", "the raw GNSS fixes", d.x_true, aside


def trust_check(res: Results) -> list[Finding]:
    """After a run: is the best filter much worse than the raw GNSS it is fed? (module doc)."""
    d = res.data
    if "pos" not in d.groups or not all(hasattr(fr, "x") for fr in res.runs.values()):
        return []  # no position, or a summary run (no per-epoch estimates)
    idx = list(d.groups["pos"].idx)
    fixes = d.model.fixes(d.z) if hasattr(d.model, "fixes") else None  # the aiding as fed
    if fixes is not None:
        raw, basis, raw_label, truth, aside = _raw_fixes(d, fixes)
        errs = _filter_rms(res, idx, fixes if truth is None else truth[..., idx])
        causes = _DRIVE_CAUSES
        if d.extras.get("start") == "moving":
            causes = (
                "a start in motion: the first seconds (heading, attitude, biases) converge; judge after "
                "convergence with eval_from_s",
                *causes,
            )
    elif "wls" in res.runs and d.has_truth:
        truth = d.x_true[..., idx]
        raw = _pos_rms((res.runs["wls"].x[..., idx] - truth)[:, d.window])
        basis, raw_label, causes = "against the truth", "the per-epoch least-squares fix (wls)", _PR_CAUSES
        aside = ""
        errs = _filter_rms(res, idx, truth)
    else:
        return []
    if not errs or not np.isfinite(raw):
        return []
    best = min(errs, key=lambda k: errs[k] if np.isfinite(errs[k]) else np.inf)
    lab = res.runs[best].label
    out = [
        Finding(
            "note",
            f"3-D position RMS {basis}: {raw_label} {raw:.3g} m{aside}; best filter {lab} {errs[best]:.3g} m",
        )
    ]
    if not errs[best] <= max(TRUST_FACTOR * raw, raw + TRUST_MARGIN_M):
        worst = ", ".join(f"{res.runs[k].label} {v:.3g} m" for k, v in errs.items())
        flagged = tuple(
            f"the check before the run: {f.text}"
            for f in d.extras.get("findings", ())
            if f.level == "warning"
        )
        out.append(
            Finding(
                "warning",
                f"this result cannot be trusted: every filter is more than {TRUST_FACTOR:g}× worse than "
                f"{raw_label} it is fed ({raw:.3g} m RMS {basis.split(';')[0]}; {worst}).",
                flagged + tuple(causes),
            )
        )
    return out


def run_messages(res: Results) -> list[Finding]:
    """Everything to tell the user about a finished run: notes, pre-run findings, the trust check."""
    d = res.data
    out = [Finding("note", n) for n in d.extras.get("notes", ())]
    out += list(d.extras.get("findings", ()))
    out += trust_check(res)
    return out


__all__ = [
    "OFFSET_MAX_SE_S",
    "TRUST_FACTOR",
    "Finding",
    "OffsetEstimate",
    "aiding_note",
    "check_drive",
    "fix_outliers",
    "heading_change_slope",
    "raw_outlier_epochs",
    "run_messages",
    "time_offset_hint",
    "trust_check",
]
