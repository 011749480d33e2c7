"""Real car drive ``drive0708``: strapdown INS + loosely coupled 1 Hz GNSS (rtkx_drive_0708).

The IMU and the motion are real (rtklibexplorer's 100 Hz MEMS IMU, Boulder CO, 549 s). There is
no second reference system, so — as the data README prescribes — the GNSS aiding the filters see
is made from the RTK-fixed solution (cm level, the truth) decimated to 1 Hz, plus navlab's noise
schedule (nominal σ, default 3 m per axis), its outlier model (default: 10 % of 10σ per channel)
and optional outages.

Monte Carlo on real data: run r is an independent noise/outlier injection on the SAME real IMU
and trajectory (run r's streams as for the simulations, ``run_streams``); the truth is identical in every
run. The filters are navlab's registered filters on the total-state closed-loop model of
:class:`navlab.ins.lc.InsGnssModel`; only the GNSS update strategy differs between them.

Channels: the GNSS position (N, E, U, m) and, by default, the car's non-holonomic constraints
(zero velocity along the vehicle's right and up axes, σ = 0.1 m/s; ``nhc_sigma_mps = 0`` turns
them off). The constraints carry only their real violation, never injected noise or outliers.

Tuning (no truth involved; measured effects in the notes of each parameter and in
navlab.ins.lc.ImuNoise): the IMU noise densities come from the static start (Allan deviation at
τ = 1 s), plus half of each second's gyro vibration as the IMU reports it, the bias random walks
from the consumer-MEMS class; the NHC σ = 0.1 m/s from the NHC channels' own innovations — at
σ = 0.2 their normalised innovation squares averaged 0.05 and 0.12 instead of 1, i.e. σ = 0.2 was
far looser than the real violation (rms innovation 0.08 m/s). The IMU time offset
(navlab.data.loaders) aligns the IMU with the RTK positions. Effect of these fixes on the CLI
example (σ = 3 m, 3 runs), position RMSE: plain KF on clean aiding 1.96 → 1.69 m; with 10 %
outliers of 10σ, Huber KF 2.27 → 1.97 m (2.04 m on seed 7, 6 runs).

Truth of the non-position states: velocity from the RTK solution, read at t + 0.13 s (the RTK
velocities lag the RTK positions; navlab.ins.lc.velocity_lag_s measures it from the file);
attitude and sensor biases from the reference solution (the closed-loop EKF aided by the RTK truth
at σ = 5 cm), so the attitude "error" is relative to that reference.

Your own drive: scenario ``own-drive`` (:class:`OwnDrive`) runs a folder in the generic CSV format
(imu.csv, gnss.csv[, truth.csv]; navlab.data.loaders) with the same model, but the user's data as
they are: the GNSS epochs and fixes as recorded (no synthetic noise or outliers unless asked for),
the receiver's per-epoch σ as the per-epoch R (whitened channels, ``use_receiver_sigmas``), an
in-motion start when there is no static segment, and the mounting rotation, lever arm and GNSS
time offset as parameters. Plain-words checks before the run (``extras["findings"]``,
navlab.data.checks) and after it (navlab.data.checks.trust_check) say when the data or the result
cannot be right.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import ClassVar

import numpy as np

from navlab.errors import NavlabError
from navlab.linalg import Array
from navlab.metrics import BOUND_SIGMAS, QuantileMetric
from navlab.noise import OutlierModel, Schedule
from navlab.params import MAX_EPOCHS, param
from navlab.scenarios.base import (
    MetricGroup,
    Scenario,
    ScenarioData,
    draw_measurement_noise,
    register_scenario,
    run_streams,
)


def horizontal_error(x_hat, data: ScenarioData):
    """Horizontal position error [m] per run and epoch (B, K+1)."""
    idx = list(data.groups["hpos"].idx)
    with np.errstate(over="ignore", invalid="ignore"):
        return np.linalg.norm(x_hat[..., idx] - data.x_true[..., idx], axis=-1)


# median and 90 % of the horizontal error, pooled over the window's epochs and the judged runs
REAL_METRICS = {
    "h_err_median": QuantileMetric(horizontal_error, 0.5, "m", "median horizontal error"),
    "h_err_p90": QuantileMetric(horizontal_error, 0.9, "m", "90 % horizontal error"),
}


def _fingerprint(data_dir: str) -> tuple:
    """Names, sizes and modification times of the files a drive is read from (cache key)."""
    from pathlib import Path

    from navlab.data.loaders import RTKX_DIR, data_root

    d = Path(data_dir) if data_dir else data_root() / RTKX_DIR
    if d.is_dir() and not (d / "imu.csv").exists() and (d / RTKX_DIR).is_dir():
        d = d / RTKX_DIR
    try:
        return tuple(
            sorted((p.name, p.stat().st_size, p.stat().st_mtime_ns) for p in d.iterdir() if p.is_file())
        )
    except OSError:
        return ()


def drive_setup(data_dir: str, epochs: int, imu_rate_hz: float, **options):
    """(recording, setup, reference) for a drive — cached while its files are unchanged.

    ``options`` (all hashable): ``own`` (a generic-CSV folder: recorded epochs), ``rate_hz``,
    ``gnss_time_offset_s``, ``start``, ``lever_arm_v_m`` (tuple), ``mount_deg`` (roll, pitch,
    yaw of the IMU in the vehicle frame; own recordings only).
    """
    return _drive_setup(data_dir, _fingerprint(data_dir), epochs, imu_rate_hz, tuple(sorted(options.items())))


@lru_cache(maxsize=4)
def _drive_setup(data_dir: str, fingerprint: tuple, epochs: int, imu_rate_hz: float, options: tuple):
    import dataclasses
    from pathlib import Path

    from navlab.data.loaders import load_generic, rtkx_drive_0708
    from navlab.ins.align import body_to_vehicle
    from navlab.ins.lc import prepare_drive, reference_solution

    o = dict(options)
    own = bool(o.pop("own", False))
    mount = o.pop("mount_deg", (0.0, 0.0, 0.0))
    d = Path(data_dir).expanduser() if data_dir else None
    generic = d is not None and ((d / "imu.csv").exists() or (d / "gnss.csv").exists())
    if own:
        if d is None:
            raise NavlabError(
                "own-drive needs a folder: set scenario.data_dir=FOLDER holding imu.csv, gnss.csv and "
                "optionally truth.csv (the generic CSV format, see docs/data.md, 'Your own drive')"
            )
        if not generic:
            raise NavlabError(
                f"{d}: no imu.csv or gnss.csv in this folder; own-drive reads the generic CSV format "
                "(docs/data.md, 'Your own drive')"
            )
        truth = d / "truth.csv"
        rec = load_generic(d / "imu.csv", d / "gnss.csv", truth if truth.exists() else None, name=d.name)
        roll, pitch, yaw = (float(a) for a in mount)
        rec = dataclasses.replace(rec, C_bv=body_to_vehicle(pitch, yaw, roll, nominal=np.eye(3)))
        setup = prepare_drive(rec, epochs=epochs, imu_rate_hz=imu_rate_hz, recorded=True, **o)
    else:
        if generic:
            raise NavlabError(
                "drive0708 is the bundled rtkx_drive_0708 recording; run a folder in the generic CSV "
                "format with --scenario own-drive (the Real data page: 'Upload your own drive')"
            )
        rec = rtkx_drive_0708(data_dir or None)
        setup = prepare_drive(rec, epochs=epochs, imu_rate_hz=imu_rate_hz, **o)
    return rec, setup, reference_solution(setup)


def fill_rows(x: Array) -> Array:
    """(K+1, d) with NaN rows filled by linear interpolation over the epochs (edges held)."""
    ok = np.isfinite(x).all(axis=1)
    if ok.all() or not ok.any():
        return x
    k = np.arange(len(x))
    return np.stack([np.interp(k, k[ok], x[ok, i]) for i in range(x.shape[1])], -1)


_START_HELP = (
    "'auto': align on a static start when the recording begins with ≥ 2 s at rest, else start in "
    "motion from GNSS; 'static' / 'moving' force one"
)


@dataclass(frozen=True)
class Drive0708Params:
    epochs: int = param(
        0, lo=0, hi=MAX_EPOCHS, help="1 Hz epochs after the static start (0: the whole drive, ≈513)"
    )
    sigma_m: float = param(
        3.0, lo=0.01, hi=1000.0, help="nominal GNSS position σ per axis (m): R0 and the noise schedule's base"
    )
    outage_start_s: float = param(
        0.0, lo=0.0, hi=1e5, help="GNSS outage start, s after epoch 0 (0: no outage)"
    )
    outage_len_s: float = param(0.0, lo=0.0, hi=1e5, help="GNSS outage length (s)")
    imu_rate_hz: float = param(
        10.0,
        lo=0.0,
        hi=1000.0,
        help="mechanisation rate: the IMU averaged over bins that start at every GNSS epoch and never "
        "straddle one, so any rate keeps each fix at its own time (0: the raw samples; higher: slower, "
        "keeps the rotation inside a bin — negligible for a car below 1 rad/s; docs/REAL_DATA.md)",
    )
    add_noise: bool = param(True, help="add the schedule's noise and outliers to the aiding positions")
    nhc_sigma_mps: float = param(
        0.1,
        lo=0.0,
        hi=100.0,
        help="σ of the car's non-holonomic constraints (zero lateral/vertical velocity) as two "
        "extra channels (0: off)",
    )
    arw_rad_rts: float = param(
        0.001,
        lo=1e-6,
        hi=1.0,
        help="gyro angle random walk at rest (rad/√s): static-start Allan deviation at 1 s",
    )
    vib_gyro_factor: float = param(
        0.5,
        lo=0.0,
        hi=10.0,
        help="share of each second's measured gyro vibration (raw std × √dt) added to the angle "
        "random walk (0: constant Q)",
    )
    vrw_mps_rts: float = param(
        0.015,
        lo=1e-6,
        hi=10.0,
        help="accelerometer velocity random walk (m/s/√s): static-start Allan deviation at 1 s",
    )
    gyro_bias_rw: float = param(
        2e-5, lo=0.0, hi=1e-1, help="gyro-bias random walk (rad/s/√s), consumer MEMS class"
    )
    accel_bias_rw: float = param(
        1e-3, lo=0.0, hi=1.0, help="accelerometer-bias random walk (m/s²/√s), consumer MEMS class"
    )
    start: str = param("auto", choices=("auto", "static", "moving"), help=_START_HELP)
    eval_from_s: float = param(
        0.0,
        lo=0.0,
        hi=1e7,
        help="errors count from this time on the recording's own time base t_s (0: from epoch 1)",
    )
    data_dir: str = param("", help="data directory (default ../shared/data or $NAVLAB_DATA)", ui=False)


@dataclass(frozen=True)
class OwnDriveParams(Drive0708Params):
    epochs: int = param(0, lo=0, hi=MAX_EPOCHS, help="GNSS epochs to use (0: all)")
    sigma_m: float = param(
        3.0,
        lo=0.01,
        hi=1000.0,
        help="GNSS position σ per axis (m) when gnss.csv has no sigma_* columns (or they are ignored); "
        "also the σ of the synthetic noise when add_noise is on",
    )
    add_noise: bool = param(
        False, help="add synthetic noise (σ = sigma_m) to the recorded fixes (outliers: set a contamination)"
    )
    use_receiver_sigmas: bool = param(
        True, help="the receiver's per-epoch sigma_n/e/u_m set the per-epoch R (off: σ = sigma_m throughout)"
    )
    gnss_rate_hz: float = param(
        0.0, lo=0.0, hi=100.0, help="use at most this many GNSS epochs per second (0: as recorded)"
    )
    gnss_time_offset_s: float = param(
        0.0,
        lo=-10.0,
        hi=10.0,
        help="added to gnss.csv's t_s (GNSS latency; the page and the CLI print the lag that best aligns "
        "the GNSS course with the IMU's yaw rate)",
    )
    mount_roll_deg: float = param(
        0.0, lo=-180.0, hi=180.0, help="IMU roll in the vehicle frame (deg): 180 for an IMU with z down"
    )
    mount_pitch_deg: float = param(0.0, lo=-90.0, hi=90.0, help="IMU pitch in the vehicle frame (deg)")
    mount_yaw_deg: float = param(
        0.0,
        lo=-180.0,
        hi=180.0,
        help="IMU yaw in the vehicle frame (deg, clockwise: IMU y axis to the right)",
    )
    lever_right_m: float = param(0.0, lo=-100.0, hi=100.0, help="GNSS antenna right of the IMU (m)")
    lever_forward_m: float = param(0.0, lo=-100.0, hi=100.0, help="GNSS antenna ahead of the IMU (m)")
    lever_up_m: float = param(0.0, lo=-100.0, hi=100.0, help="GNSS antenna above the IMU (m)")
    data_dir: str = param(
        "", help="folder with imu.csv, gnss.csv[, truth.csv] (generic CSV format)", ui=False
    )


#: Smallest receiver σ taken as a real one [m]: below it a fix claims to be exact.
MIN_RX_SIGMA_M = 1e-3


def check_receiver_sigmas(gnss, sigma_m: float) -> None:
    """Refuse receiver σ's of (almost) 0: the filters would trust those fixes blindly."""
    for col in ("sigma_n_m", "sigma_e_m", "sigma_u_m"):
        v = gnss[col].to_numpy()
        bad = int(np.sum(v < MIN_RX_SIGMA_M))
        if bad:
            raise NavlabError(
                f"gnss.csv: {col} is below {MIN_RX_SIGMA_M * 1000:g} mm on {bad} of {len(v)} fixes (smallest "
                f"{np.min(v):g} m): a σ of 0 claims an exact fix, which the filters then trust blindly; give "
                "each fix's 1-σ uncertainty in metres, or set use_receiver_sigmas = false (CLI: --set "
                "scenario.use_receiver_sigmas=false; app: turn off 'R from the receiver's σ') to use "
                f"sigma_m = {sigma_m:g} m for every fix"
            )


def _imu_noise(p: Drive0708Params):
    """The IMU noise densities of the parameters."""
    from navlab.ins.lc import ImuNoise

    return ImuNoise(
        float(p.arw_rad_rts),
        float(p.vrw_mps_rts),
        float(p.gyro_bias_rw),
        float(p.accel_bias_rw),
        float(p.vib_gyro_factor),
    )


def _receiver_sigma(own: bool, p: Drive0708Params, rec, setup) -> Array | None:
    """(K+1, 3) per-epoch σ of the fixes from the receiver (with the synthetic σ on top when
    ``add_noise``), or None: own recordings with receiver σ's that are used only.
    """
    if not (own and p.use_receiver_sigmas and setup.gnss_sigma is not None):
        return None
    check_receiver_sigmas(rec.gnss, p.sigma_m)
    return setup.gnss_sigma if not p.add_noise else np.hypot(setup.gnss_sigma, p.sigma_m)


def _gnss_aiding(own, p, setup, sigma, rx_sigma, std, noise, var, mask) -> tuple[Array, Array, Array]:
    """The aiding positions, their true variances and the R(t) schedule: (z, var, std2).

    An own recording: the recorded fixes, synthetic noise and outliers only when asked for; rtkx:
    the RTK truth plus the schedule's noise (the recording has no second receiver).
    """
    K = setup.K
    if own:
        # the recorded fixes as recorded; synthetic noise and outliers only when asked for
        inject = np.where(mask, noise, 0.0) + (np.where(mask, 0.0, noise) if p.add_noise else 0.0)
        z = setup.gnss_pos[None] + inject
        clean_var = (rx_sigma if rx_sigma is not None else sigma) ** 2
        var = np.where(mask, var + (0.0 if p.add_noise else clean_var), np.broadcast_to(clean_var, var.shape))
        return z, var, np.broadcast_to(clean_var, (K + 1, 3)).copy()
    return setup.p_true[None] + (noise if p.add_noise else np.zeros_like(noise)), var, std**2  # (B, K+1, 3)


def _cut_outage(z: Array, setup, p: Drive0708Params) -> None:
    """Remove the fixes of epoch 0 and of the GNSS outage (``outage_start_s``, s after epoch 0) from ``z``."""
    z[:, 0] = np.nan
    if p.outage_len_s > 0 and p.outage_start_s > 0:
        dt = setup.t - setup.t[0]
        z[:, (dt >= p.outage_start_s) & (dt < p.outage_start_s + p.outage_len_s)] = np.nan


def _with_nhc(z, var, bias, mask, std2, nhc_sigma_mps: float, B: int):
    """The two NHC pseudo-measurements (lateral and vertical vehicle velocity 0, real noise only)
    appended as channels for ``B`` runs: (z, var, bias, mask, std2).
    """
    K1 = z.shape[1]
    nh = np.full((B, K1, 2), nhc_sigma_mps**2)
    z = np.concatenate([z, np.zeros((B, K1, 2))], axis=2)
    z[:, 0] = np.nan
    var = np.concatenate([var, nh], axis=2)
    bias = np.concatenate([bias, np.zeros((B, K1, 2))], axis=2)
    mask = np.concatenate([mask, np.zeros((B, K1, 2), bool)], axis=2)
    std2 = np.concatenate([std2, nh[0]], axis=1)
    return z, var, bias, mask, std2


def _true_states(setup, ref, B: int) -> tuple[Array, Array]:
    """(B, K+1, 15) truth of the IMU point (attitude 0 against the reference), and the lever arm
    N, E, U per epoch (K+1, 3) from the antenna to it.
    """
    K = setup.K
    # truth of the IMU point: the antenna truth minus the lever arm (reference attitude)
    lever_neu = (ref.C_bn[0] @ (setup.C_bv.T @ setup.lever_arm_v))[:, [1, 0, 2]]
    p_true = fill_rows(setup.p_true) - lever_neu
    v_true = fill_rows(setup.v_true)
    x_true = np.concatenate([np.zeros((K + 1, 3)), v_true, p_true, ref.bias_g[0], ref.bias_a[0]], axis=1)
    return np.broadcast_to(x_true, (B, K + 1, 15)).copy(), lever_neu


def _initial_states(setup, fixes: Array, lever_neu: Array, B: int, skip: Array | None = None) -> Array:
    """(B, 15) x0: the setup's, each run of an in-motion start at its own first fix.

    ``skip`` (K+1,): epochs whose recorded fix the pre-run check calls an outlier
    (:func:`navlab.data.checks.raw_outlier_epochs`). A start there would put every filter tens of
    metres off with a P0 of the receiver's σ, and a robust filter then rejects the good fixes
    that follow (issue 24: recording (c), seeds 2 and 4). The run starts instead from the first
    fix the check accepts, carried back to epoch 0 with the initial (GNSS) velocity.
    """
    x0 = np.broadcast_to(setup.x0, (B, 15)).copy()
    if setup.start == "moving":  # each run starts at its own first fix (the filters' honest start)
        good = np.isfinite(fixes).all(axis=2)
        if skip is not None:
            good &= ~np.asarray(skip, bool)[None]
        k = good.argmax(axis=1)
        ok0 = good.any(axis=1)
        v_neu = np.asarray(setup.x0)[[4, 3, 5]]  # state order v_E, v_N, v_U; positions N, E, U
        dt = (setup.t[k] - setup.t[0])[:, None]
        first = fixes[np.arange(B), k] - lever_neu[k] - v_neu[None] * dt
        x0[ok0, 6:9] = first[ok0]
    return x0


def _eval_window(setup, eval_from_s: float) -> tuple[Array, bool]:
    """The epochs judged (from epoch 1 and ``eval_from_s`` on, with a truth) and whether there is a truth."""
    truth_ok = np.isfinite(setup.p_true).all(axis=1)
    has_truth = bool(truth_ok.mean() > 0.5)
    window = (np.arange(setup.K + 1) >= 1) & (setup.t >= eval_from_s - 1e-9)
    if has_truth:
        window &= truth_ok
    if not window.any():
        raise NavlabError(
            f"eval_from_s = {eval_from_s:g} s leaves no epoch to judge (the epochs run from "
            f"{setup.t[0]:.1f} to {setup.t[-1]:.1f} s on the recording's time base)"
        )
    return window, has_truth


def _divergence_bound(model) -> float | None:
    """Whitened channels: the error bound of the divergence rule in metres (else None: the default)."""
    if not model.whitened:
        return None
    return BOUND_SIGMAS * float(np.median(np.max(model.scale[1:, :3], axis=1)))


def _drive_groups() -> dict[str, MetricGroup]:
    """Position (3-D, horizontal), velocity and attitude (deg, against the reference)."""
    return {
        "pos": MetricGroup((6, 7, 8), "m", "position (3-D)"),
        "hpos": MetricGroup((6, 7), "m", "horizontal position"),
        "vel": MetricGroup((3, 4, 5), "m/s", "velocity"),
        "att": MetricGroup((0, 1, 2), "deg", "attitude vs reference", float(np.degrees(1.0))),
    }


def _drive_extras(rec, setup, rx_sigma: Array | None, sigma: Array) -> dict:
    """What the pages show besides the filters: source, origin, tracks, σ of the fixes, times."""
    return {
        "metrics": REAL_METRICS,
        "source": rec.source,
        "recording": rec.name,
        "origin_deg": (
            float(np.degrees(setup.lat0_rad)),
            float(np.degrees(setup.lon0_rad)),
            setup.h0_m,
        ),
        "xy_idx": (7, 6),  # east, north columns of the state for plots
        "gnss_track": setup.gnss_pos,
        "p_true_antenna": setup.p_true,
        "fix_sigma_m": (rx_sigma if rx_sigma is not None else np.broadcast_to(sigma, (setup.K + 1, 3))),
        "t_abs_s": setup.t,
        "start": setup.start,
    }


_BAND = {"r_min": 0.25, "r_max": 16.0}  # the adaptive filters' R̂ band on a real drive


@register_scenario
class Drive0708(Scenario):
    key = "drive0708"
    label = "Real car drive: INS + loosely coupled GNSS"
    paper = "real data: rtklibexplorer/GNSS_IMU drive_0708 (BSD-3-Clause)"
    summary = (
        "A real 100 Hz MEMS IMU in a car (Boulder, 549 s). A strapdown INS runs closed loop; 1 Hz "
        "GNSS positions made from the RTK truth plus noise and outliers correct it through each "
        "filter's update."
    )
    Params = Drive0708Params
    default_filters = ("kf", "chi2-kf", "huber-kf", "vb-akf", "hakf", "sage-husa", "irakf")
    # each epoch holds three GNSS axes and the two NHC channels: a whole-epoch χ² gate rejects
    # the clean channels with an outlying axis and loses lock; gate each channel instead
    # the χ² gate per channel (one bad axis does not drop a fix); the adaptive filters' R̂ kept within
    # σ ∈ [0.5, 4] × the receiver's reported σ (ALGORITHMS.md §3.1, §4.1 step 4; docs/REAL_DATA.md)
    filter_defaults: ClassVar[dict] = {
        "chi2-kf": {"per_channel": True},
        **{key: dict(_BAND) for key in ("sage-husa", "rrae", "rakf", "rsshakf", "vb-akf")},
        # issue 24, recording (c) (10 % of the fixes 30–100 m off): the paper's β update (eq. 21) fed
        # the raw residual, so R̂ absorbed the outliers (median 145–183× the receiver's σ²) and HAKF
        # leaned on the drifting INS (up to 1.9× the clean fixes); its Huber-weighted β keeps it ≤ 1.3×
        "hakf": {**_BAND, "robust_beta": True},
        # the same recording: IRAKF's parallel SKF (plain KF, R0) absorbed the outliers, then flagged
        # every good fix (REJECTED_AUX): no update, the INS drifted, 4 of 10 seeds diverged; gating
        # the SKF's own update on its detections keeps it clean (all 10 within 1.3×)
        "irakf": {**_BAND, "skf_gated": True},
    }
    default_runs = 10
    simulated = False
    linear = False  # nonlinear model (no probe run needed by the app)
    headline = ("pos", "hpos")

    own: ClassVar[bool] = False

    def _setup(self):
        p = self.params
        opts: dict = {"start": p.start}
        if self.own:
            opts.update(
                own=True,
                rate_hz=float(p.gnss_rate_hz),
                gnss_time_offset_s=float(p.gnss_time_offset_s),
                lever_arm_v_m=(float(p.lever_right_m), float(p.lever_forward_m), float(p.lever_up_m)),
                mount_deg=(float(p.mount_roll_deg), float(p.mount_pitch_deg), float(p.mount_yaw_deg)),
            )
        return drive_setup(p.data_dir, int(p.epochs), float(p.imu_rate_hz), **opts)

    def simulate(
        self, schedule: Schedule, outliers: OutlierModel, runs: Sequence[int], seed: int
    ) -> ScenarioData:
        from navlab.data.checks import aiding_note, check_drive
        from navlab.ins.lc import STATE_NAMES, InsGnssModel

        p = self.params
        rec, setup, ref = self._setup()
        K = setup.K
        sigma = np.full(3, p.sigma_m)
        rx_sigma = _receiver_sigma(self.own, p, rec, setup)
        model = InsGnssModel(
            setup, ref, sigma, noise=_imu_noise(p), nhc_sigma_mps=p.nhc_sigma_mps, gnss_sigma_k=rx_sigma
        )
        streams = run_streams(seed, runs)
        B = len(streams)
        std = schedule.std(sigma, K)
        noise, var, bias, mask = draw_measurement_noise(streams, std, outliers)
        z, var, std2 = _gnss_aiding(self.own, p, setup, sigma, rx_sigma, std, noise, var, mask)
        fixes = z.copy()  # the aiding positions the filters are fed (N, E, U m), epoch 0 included
        _cut_outage(z, setup, p)
        channels = ("p_N", "p_E", "p_U")
        if model.nhc:  # pseudo-measurements 0 = lateral / vertical vehicle velocity: real noise only
            z, var, bias, mask, std2 = _with_nhc(z, var, bias, mask, std2, p.nhc_sigma_mps, B)
            channels += ("v_right", "v_up")
        if model.whitened:  # per-epoch receiver σ: channels in units of σ_k (R0 = I)
            z = model.whiten(z)
            var = var / model.scale[None] ** 2
            bias = bias / model.scale[None]
            std2 = std2 / model.scale**2
        x_true, lever_neu = _true_states(setup, ref, B)
        raw_outliers = None
        if self.own:  # fixes the pre-run check calls outliers: no start there, none in the raw figure
            from navlab.data.checks import raw_outlier_epochs

            raw_outliers = raw_outlier_epochs(rec, setup, p.sigma_m)
        window, has_truth = _eval_window(setup, p.eval_from_s)
        data = ScenarioData(
            scenario=self.key,
            divergence_bound=_divergence_bound(model),
            t=setup.t - setup.t[0],
            model=model,
            x_true=x_true,
            z=z,
            R_true=var,
            R_schedule=std2,
            outlier_mask=mask,
            bias=bias,
            x0=_initial_states(setup, fixes, lever_neu, B, raw_outliers),
            P0=setup.P0,
            runs=np.asarray(runs),
            state_names=STATE_NAMES,
            channel_names=channels,
            channel_units=(("σ",) * 3 if model.whitened else ("m",) * 3)
            + ("m/s", "m/s")[: len(channels) - 3],
            groups=_drive_groups(),
            window=window,
            has_truth=has_truth,
            extras=_drive_extras(rec, setup, rx_sigma, sigma),
        )
        data.extras["notes"] = [aiding_note(self, setup, rx_sigma), *setup.notes]
        data.extras["findings"] = check_drive(rec, setup, p.sigma_m) if self.own else []
        if raw_outliers is not None:  # the trust check leaves them out of the raw figure
            data.extras["raw_outliers"] = raw_outliers
        return data


@register_scenario
class OwnDrive(Drive0708):
    key = "own-drive"
    label = "Your own drive: IMU + GNSS in the generic CSV format"
    paper = "your data (generic navlab CSV)"
    summary = (
        "Your own IMU and GNSS recording (imu.csv, gnss.csv[, truth.csv]): the fixes as recorded, the "
        "receiver's σ per epoch, an in-motion start when there is no static segment, mounting, lever arm "
        "and GNSS time offset as parameters, and checks that say when the result cannot be right."
    )
    Params = OwnDriveParams
    outlier_defaults: ClassVar[dict] = {"mixture": {"contamination": 0.0}}
    default_runs = 1
    own = True
    #: needs a folder of the user's files (data_dir): the Real data page uploads one; pages without
    #: an upload (Compare, Sweep) should not offer it
    user_data: ClassVar[bool] = True
