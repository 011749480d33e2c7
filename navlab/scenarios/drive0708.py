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

A folder in the generic CSV format (imu.csv, gnss.csv[, truth.csv]; see navlab.data.loaders) can
be given with ``data_dir``: its GNSS positions are then the aiding (noise is still added unless
``add_noise`` is false) and truth.csv, if present, the truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import ClassVar

import numpy as np

from navlab.data.loaders import load_drive
from navlab.noise import OutlierModel, Schedule
from navlab.params import param
from navlab.scenarios.base import (
    MetricGroup,
    Scenario,
    ScenarioData,
    draw_measurement_noise,
    register_scenario,
    run_streams,
)


def h_err_median(x_hat, data: ScenarioData, ok_runs) -> float:
    """Median horizontal position error [m] over the window's epochs and the non-diverged runs."""
    idx = list(data.groups["hpos"].idx)
    e = np.linalg.norm(x_hat[..., idx] - data.x_true[..., idx], axis=-1)[ok_runs][:, data.window]
    e = e[np.isfinite(e)]
    return float(np.median(e)) if e.size else float("nan")


def h_err_p90(x_hat, data: ScenarioData, ok_runs) -> float:
    """90th percentile of the horizontal position error [m]."""
    idx = list(data.groups["hpos"].idx)
    e = np.linalg.norm(x_hat[..., idx] - data.x_true[..., idx], axis=-1)[ok_runs][:, data.window]
    e = e[np.isfinite(e)]
    return float(np.quantile(e, 0.9)) if e.size else float("nan")


REAL_METRICS = {"h_err_median": (h_err_median, "m"), "h_err_p90": (h_err_p90, "m")}


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


def drive_setup(data_dir: str, epochs: int, imu_rate_hz: float):
    """(recording, setup, reference) for a drive — cached while its files are unchanged."""
    return _drive_setup(data_dir, _fingerprint(data_dir), epochs, imu_rate_hz)


@lru_cache(maxsize=4)
def _drive_setup(data_dir: str, fingerprint: tuple, epochs: int, imu_rate_hz: float):
    from navlab.ins.lc import prepare_drive, reference_solution

    rec = load_drive(data_dir or None)
    setup = prepare_drive(rec, epochs=epochs, imu_rate_hz=imu_rate_hz)
    return rec, setup, reference_solution(setup)


@dataclass(frozen=True)
class Drive0708Params:
    epochs: int = param(
        0, lo=0, hi=100000, help="1 Hz epochs after the static start (0: the whole drive, ≈513)"
    )
    sigma_m: float = param(
        3.0, lo=0.01, hi=1000.0, help="nominal GNSS position σ per axis (m): R0 and the noise schedule's base"
    )
    outage_start_s: float = param(
        0.0, lo=0.0, hi=1e5, help="GNSS outage start, s after epoch 0 (0: no outage)"
    )
    outage_len_s: float = param(0.0, lo=0.0, hi=1e5, help="GNSS outage length (s)")
    imu_rate_hz: float = param(
        10.0, lo=0.0, hi=1000.0, help="mechanisation rate: IMU averaged into bins (0: raw 100 Hz)"
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
    data_dir: str = param(
        "", help="data directory (default ../shared/data or $NAVLAB_DATA), or a generic-CSV folder", ui=False
    )


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
    filter_defaults: ClassVar[dict] = {"chi2-kf": {"per_channel": True}}
    default_runs = 10
    simulated = False
    linear = False  # nonlinear model (no probe run needed by the app)
    headline = ("pos", "hpos")

    def simulate(
        self, schedule: Schedule, outliers: OutlierModel, runs: Sequence[int], seed: int
    ) -> ScenarioData:
        from navlab.ins.lc import STATE_NAMES, ImuNoise, InsGnssModel

        p = self.params
        rec, setup, ref = drive_setup(p.data_dir, int(p.epochs), float(p.imu_rate_hz))
        K = setup.K
        sigma = np.full(3, p.sigma_m)
        noise = ImuNoise(
            float(p.arw_rad_rts),
            float(p.vrw_mps_rts),
            float(p.gyro_bias_rw),
            float(p.accel_bias_rw),
            float(p.vib_gyro_factor),
        )
        model = InsGnssModel(setup, ref, sigma, noise=noise, nhc_sigma_mps=p.nhc_sigma_mps)
        streams = run_streams(seed, runs)
        B = len(streams)
        std = schedule.std(sigma, K)
        noise, var, bias, mask = draw_measurement_noise(streams, std, outliers)
        has_truth = bool(np.isfinite(setup.p_true).all())
        base = (
            setup.p_true
            if has_truth and rec.truth is not None and rec.name.startswith("rtkx")
            else setup.gnss_pos
        )
        z = base[None] + (noise if p.add_noise else 0.0)
        z[:, 0] = np.nan
        if p.outage_len_s > 0 and p.outage_start_s > 0:
            dt = setup.t - setup.t[0]
            z[:, (dt >= p.outage_start_s) & (dt < p.outage_start_s + p.outage_len_s)] = np.nan
        std2 = std**2
        channels = ("p_N", "p_E", "p_U")
        if model.nhc:  # pseudo-measurements 0 = lateral / vertical vehicle velocity: real noise only
            nh = np.full((B, K + 1, 2), p.nhc_sigma_mps**2)
            z = np.concatenate([z, np.zeros((B, K + 1, 2))], axis=2)
            z[:, 0] = np.nan
            var = np.concatenate([var, nh], axis=2)
            bias = np.concatenate([bias, np.zeros((B, K + 1, 2))], axis=2)
            mask = np.concatenate([mask, np.zeros((B, K + 1, 2), bool)], axis=2)
            std2 = np.concatenate([std2, nh[0]], axis=1)
            channels += ("v_right", "v_up")
        x_true = np.concatenate(
            [np.zeros((K + 1, 3)), setup.v_true, setup.p_true, ref.bias_g[0], ref.bias_a[0]], axis=1
        )
        x_true = np.broadcast_to(x_true, (B, K + 1, 15)).copy()
        return ScenarioData(
            scenario=self.key,
            t=setup.t - setup.t[0],
            model=model,
            x_true=x_true,
            z=z,
            R_true=var,
            R_schedule=std2,
            outlier_mask=mask,
            bias=bias,
            x0=np.broadcast_to(setup.x0, (B, 15)).copy(),
            P0=setup.P0,
            runs=np.asarray(runs),
            state_names=STATE_NAMES,
            channel_names=channels,
            channel_units=("m", "m", "m", "m/s", "m/s")[: len(channels)],
            groups={
                "pos": MetricGroup((6, 7, 8), "m", "position (3-D)"),
                "hpos": MetricGroup((6, 7), "m", "horizontal position"),
                "vel": MetricGroup((3, 4, 5), "m/s", "velocity"),
                "att": MetricGroup((0, 1, 2), "deg", "attitude vs reference", float(np.degrees(1.0))),
            },
            window=np.arange(K + 1) >= 1,
            has_truth=has_truth,
            extras={
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
                "t_abs_s": setup.t,
            },
        )
