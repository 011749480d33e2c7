"""Plain-words checks of a user's recording before a run, and of the result after it.

Before a run (:func:`check_drive`): sample rate and gaps, gravity magnitude and sign on the
vehicle's z axis, the IMU's tilt in the vehicle frame, gyro units and sign (the IMU's heading
change against the GNSS course change), and a GNSS time-offset hint (the lag that best aligns the
GNSS course rate with the IMU's yaw rate).

After a run (:func:`trust_check`): when every filter's position error exceeds the raw GNSS's own
error by :data:`TRUST_FACTOR` (against the truth, or against the GNSS fixes themselves when there
is no truth — labelled so), the result cannot be trusted, and the likely causes are listed.

Every function returns :class:`Finding` s — pure data; the CLI prints them to stderr, the Real
data page shows them as notes and warnings.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

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


def _course(v_enu: Array) -> Array:
    return np.arctan2(v_enu[:, 0], v_enu[:, 1])  # clockwise from north


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
    crs = np.unwrap(_course(v_enu))
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


def time_offset_hint(
    t_g: Array, v_enu: Array, t_imu: Array, w_up: Array, max_lag_s: float = 1.0, min_speed_mps: float = 4.0
) -> float:
    """The GNSS time offset [s] that best aligns the GNSS course rate with the IMU's yaw rate.

    Grid search (10 ms) of L minimising mean((−ψ̇_GNSS(t) − ω_up(t + L))²) over moving epochs,
    the IMU rate averaged over each GNSS interval; the returned L is the value to ADD to the GNSS
    time stamps. NaN when the vehicle hardly turns.
    """
    sp = np.hypot(v_enu[:, 0], v_enu[:, 1])
    crs = np.unwrap(_course(v_enu))
    rate = -np.gradient(crs, t_g)
    dtg = float(np.median(np.diff(t_g)))
    inside = (t_g - max_lag_s - dtg >= t_imu[0]) & (t_g + max_lag_s + dtg <= t_imu[-1])
    ok = (sp > min_speed_mps) & np.isfinite(rate) & inside
    if ok.sum() < 20 or np.std(rate[ok]) < 0.02:
        return float("nan")
    dt = np.diff(t_imu, append=t_imu[-1])
    cum = np.r_[0.0, np.cumsum(w_up * dt)][:-1]
    lags = np.arange(-max_lag_s, max_lag_s + 1e-9, 0.01)
    tt = t_g[ok]
    cost = []
    for L in lags:  # centred average of the IMU rate over one GNSS interval around t + L
        a, b = tt + L - dtg, tt + L + dtg
        w_avg = (np.interp(b, t_imu, cum) - np.interp(a, t_imu, cum)) / (b - a)
        cost.append(np.mean((rate[ok] - w_avg) ** 2))
    return float(lags[int(np.argmin(cost))])


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
    """The GNSS time offset that best aligns the course with the yaw rate (receiver velocities only)."""
    from navlab.ins.lc import velocity_lag_s

    offset = float(getattr(setup, "gnss_time_offset_s", 0.0))
    hint = time_offset_hint(tg + offset, v_enu, ti, w_up)
    if not np.isfinite(hint):
        return []
    # a receiver's velocities may lag its positions (RTKLIB: ≈ 0.12 s); measurable only on
    # precise fixes (σ < 0.2 m), else the velocities are taken as on the positions' time base
    sig = g[["sigma_n_m", "sigma_e_m"]].to_numpy()
    d_v = 0.0
    if np.isfinite(sig).all() and np.nanmedian(sig) < 0.2:
        d_v = velocity_lag_s(tg, _gnss_positions(g, setup), v_enu)
    total = offset + hint + d_v
    text = (
        f"GNSS time offset: the GNSS course best matches the IMU's yaw rate with gnss_time_offset_s "
        f"≈ {total:+.2f} s (now {offset:+.2f} s"
        + (f"; the receiver's velocities lag its positions by {d_v:.2f} s" if d_v else "")
        + ")"
    )
    return [Finding("warning" if abs(total - offset) > 0.1 else "note", text)]


def check_drive(rec: DriveRecording, setup: DriveSetup) -> list[Finding]:
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
    return out


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


def trust_check(res: Results) -> list[Finding]:
    """After a run: is the best filter much worse than the raw GNSS it is fed? (module doc)."""
    d = res.data
    idx = list(d.groups["pos"].idx) if "pos" in d.groups else None
    if idx is None:
        return []
    W = d.window
    if not all(hasattr(fr, "x") for fr in res.runs.values()):
        return []  # a summary run keeps no per-epoch estimates
    fixes = d.model.fixes(d.z) if hasattr(d.model, "fixes") else None  # the aiding as fed
    errs: dict[str, float] = {}
    if fixes is not None:
        p_ant = d.extras.get("p_true_antenna")
        if d.has_truth and p_ant is not None:
            raw = _pos_rms((fixes - p_ant[None])[:, W])
            basis = "against the truth"
            for key, fr in res.runs.items():
                ok = ~fr.diverged
                errs[key] = _pos_rms((fr.x[..., idx] - d.x_true[..., idx])[ok][:, W]) if ok.any() else np.inf
        else:
            sig = np.asarray(d.extras.get("fix_sigma_m"), float)
            raw = float(np.sqrt(np.nanmean(np.sum(sig[W] ** 2, axis=-1))))
            basis = "against the GNSS fixes themselves (no truth): the raw figure is the GNSS's stated σ"
            for key, fr in res.runs.items():
                ok = ~fr.diverged
                errs[key] = _pos_rms((fr.x[..., idx] - fixes)[ok][:, W]) if ok.any() else np.inf
        causes = _DRIVE_CAUSES
        if d.extras.get("start") == "moving":
            causes = (
                "a start in motion: the first seconds (heading, attitude, biases) converge; judge after "
                "convergence with eval_from_s",
                *causes,
            )
        raw_label = "the raw GNSS fixes"
    elif "wls" in res.runs and d.has_truth:
        fr = res.runs["wls"]
        raw = _pos_rms((fr.x[..., idx] - d.x_true[..., idx])[:, W])
        basis = "against the truth"
        for key, fr in res.runs.items():
            if key != "wls":
                ok = ~fr.diverged
                errs[key] = _pos_rms((fr.x[..., idx] - d.x_true[..., idx])[ok][:, W]) if ok.any() else np.inf
        causes = _PR_CAUSES
        raw_label = "the per-epoch least-squares fix (wls)"
    else:
        return []
    errs = {k: v for k, v in errs.items() if k != "wls" or fixes is None}
    if not errs or not np.isfinite(raw):
        return []
    best = min(errs, key=lambda k: errs[k] if np.isfinite(errs[k]) else np.inf)
    lab = res.runs[best].label
    out = [
        Finding(
            "note",
            f"position RMS {basis}: {raw_label} {raw:.3g} m; best filter {lab} {errs[best]:.3g} m",
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
    "TRUST_FACTOR",
    "Finding",
    "aiding_note",
    "check_drive",
    "heading_change_slope",
    "run_messages",
    "time_offset_hint",
    "trust_check",
]
