"""Real urban pseudoranges ``smartloc-berlin``: smartLoc Berlin Potsdamer Platz (TU Chemnitz).

283 s, 1372 epochs at ≈5 Hz of GPS + GLONASS pseudoranges in a deep urban canyon, with odometry
(speed, yaw rate) and NovAtel SPAN ground truth. Non-line-of-sight reception makes the errors
heavy-tailed and mostly positive: the real test for robust and adaptive pseudorange filters.

Model (nonlinear, n = 9): x = [E, N, U (m, from a local origin), v_E, v_N, v_U (m/s),
c·δt_GPS, c·δt_GLO (m), c·δṫ (m/s)] — one clock per constellation, a common drift.

* Motion (odometry-driven, linear given the measured yaw rate ω_k): the horizontal velocity is
  rotated by ω Δt each epoch (a car turns its velocity with its heading), position integrates
  velocity, v_U is a damped random walk; white accelerations σ_a (m/s²), clock random walks.
* Measurements, one channel per satellite plus the odometry speed, WHITENED: z_j = ρ_j/σ_j,
  h_j(x) = (‖r_sat,j − r(x)‖ + ω_e/c (x_s y_r − y_s x_r) + c·δt_sys(j))/σ_j (the second term is
  the Earth-rotation/Sagnac correction of satellite positions given at transmit time) and
  z_speed = s_odo/σ_s, h = ‖v_h‖/σ_s. σ_j comes from the variance model (default the
  C/N0-and-elevation model σ² = a·10^(−C/N0/10)/sin²(el); "file" uses the file's variance column).
  Whitening lets every navlab filter use the nominal R0 = I although σ_j changes per epoch: an
  adaptive filter's R̂ is then a variance MULTIPLIER per satellite relative to the model.
* Truth: SPAN positions; velocities by differencing them; clock "truth" = the per-constellation
  median of (ρ − range at the true position) — used only for NEES.
* The filters start at epoch 0 from a robust (Huber-reweighted, C/N0-weighted) least-squares fix
  of the epoch-0 pseudoranges, with zero velocity and a large P0 (heading unknown).

Monte Carlo on real data: the pseudoranges are real, so every run sees the same errors; the
default is B = 1 and no injected contamination (``outlier_defaults`` sets the mixture's α to 0).
With ``--contamination α`` each run adds its own independent outliers (κσ, whitened units) on
top of the real ones — a stress test of the robust updates.

Filters that gate whole epochs (``chi2-kf`` in its default mode) lock out in this canyon: nearly
every epoch holds some non-line-of-sight range, the epoch is rejected, the prediction drifts and
every later epoch fails the gate too. Use ``--set chi2-kf.per_channel=true`` to gate per satellite.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import ClassVar

import numpy as np

from navlab.data.loaders import SMARTLOC_SOURCE, smartloc_berlin_pp
from navlab.filters.linalg import Array
from navlab.ins.earth import OMEGA_IE_RADPS, ecef_to_geodetic, rot_ecef_to_enu
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
from navlab.scenarios.drive0708 import REAL_METRICS

C_LIGHT = 299792458.0
STATE_NAMES = ("E", "N", "U", "v_E", "v_N", "v_U", "cb_GPS", "cb_GLO", "cd")
SYSTEM_NAMES = {1: "G", 2: "S", 4: "R", 8: "E", 16: "J", 32: "C"}


@dataclass(frozen=True, eq=False)
class PrEpochs:
    """Pseudoranges arranged on (K+1, m_sat) grids; NaN where a satellite is not tracked."""

    t: Array  # (K+1,)
    rho: Array  # (K+1, ms) pseudorange [m]
    sat: Array  # (K+1, ms, 3) ECEF [m] (0 where missing)
    var_file: Array  # (K+1, ms)
    el_deg: Array
    cn0: Array
    sys_idx: Array  # (ms,) 0 GPS, 1 GLONASS
    names: tuple[str, ...]
    speed: Array  # (K+1,)
    yaw_rate: Array  # (K+1,)
    truth_ecef: Array  # (K+1, 3)


def load_epochs(data_dir: str) -> PrEpochs:
    """The recording on epoch grids, cached while its files are unchanged."""
    from navlab.data.loaders import SMARTLOC_DIR, data_root

    d = data_root(data_dir or None)
    d = d / SMARTLOC_DIR if (d / SMARTLOC_DIR).is_dir() else d
    try:
        fp = tuple(sorted((p.name, p.stat().st_size, p.stat().st_mtime_ns) for p in d.iterdir()))
    except OSError:
        fp = ()
    return _load_epochs(data_dir, fp)


@lru_cache(maxsize=2)
def _load_epochs(data_dir: str, fingerprint: tuple) -> PrEpochs:
    rec = smartloc_berlin_pp(data_dir or None)
    pr = rec.pr
    t = np.unique(pr.t_s.to_numpy())
    keys = sorted({(int(s), int(i)) for s, i in zip(pr.system, pr.sat_id, strict=True)})
    col = {k: j for j, k in enumerate(keys)}
    K1, ms = len(t), len(keys)
    ti = np.searchsorted(t, pr.t_s.to_numpy())
    cj = np.array([col[(int(s), int(i))] for s, i in zip(pr.system, pr.sat_id, strict=True)])
    rho = np.full((K1, ms), np.nan)
    sat = np.zeros((K1, ms, 3))
    var = np.full((K1, ms), np.nan)
    el = np.full((K1, ms), np.nan)
    cn0 = np.full((K1, ms), np.nan)
    rho[ti, cj] = pr.pseudorange_m
    sat[ti, cj] = pr[["sat_x_m", "sat_y_m", "sat_z_m"]].to_numpy()
    var[ti, cj] = pr.var_m2
    el[ti, cj] = pr.elevation_deg
    cn0[ti, cj] = pr.cn0_dbhz
    sys_idx = np.array([0 if s == 1 else 1 for s, _ in keys])
    names = tuple(f"{SYSTEM_NAMES.get(s, '?')}{i:02d}" if s == 1 else f"{SYSTEM_NAMES.get(s, '?')}{i}"
                  for s, i in keys)
    od = rec.odom
    speed = np.interp(t, od.t_s, od.speed_mps)
    yaw = np.interp(t, od.t_s, od.yaw_rate_radps)
    gt = rec.truth
    truth = np.stack([np.interp(t, gt.t_s, gt[c]) for c in ("x_m", "y_m", "z_m")], -1)
    return PrEpochs(t, rho, sat, var, el, cn0, sys_idx, names, speed, yaw, truth)


def geometric_range(sat: Array, r: Array) -> tuple[Array, Array]:
    """Range with the Sagnac correction and the unit vectors receiver→satellite (ECEF).

    sat (..., ms, 3), r (..., 3) -> range (..., ms), e (..., ms, 3).
    """
    d = sat - r[..., None, :]
    rng = np.linalg.norm(d, axis=-1)
    sagnac = OMEGA_IE_RADPS / C_LIGHT * (sat[..., 0] * r[..., None, 1] - sat[..., 1] * r[..., None, 0])
    return rng + sagnac, d / rng[..., None]


def robust_ls_fix(rho: Array, sat: Array, sigma: Array, sys_idx: Array, r0: Array | None = None,
                  huber_k: float = 1.5, iters: int = 15) -> tuple[Array, Array]:
    """Huber-reweighted weighted least squares fix of one epoch: (r ECEF (3,), clocks (2,))."""
    ok = np.isfinite(rho)
    r = np.zeros(3) if r0 is None else np.array(r0, float)
    clk = np.zeros(2)
    w_h = np.ones(ok.sum())
    S = np.eye(2)[sys_idx[ok]]
    for it in range(iters):
        rng, e = geometric_range(sat[ok], r)
        res = rho[ok] - rng - S @ clk
        if it >= 4:  # Huber weights once the geometry has converged
            u = np.abs(res / sigma[ok])
            w_h = np.where(u <= huber_k, 1.0, huber_k / np.maximum(u, 1e-12))
        A = np.concatenate([-e, S], axis=1)
        W = w_h / sigma[ok] ** 2
        has = S.sum(axis=0) > 0
        A = A[:, np.r_[True, True, True, has]]
        N = A.T @ (A * W[:, None])
        dx = np.linalg.solve(N + 1e-9 * np.eye(N.shape[0]), A.T @ (W * res))
        r = r + dx[:3]
        clk[has] += dx[3:]
    return r, clk


def variance_model(ep: PrEpochs, which: str, a: float) -> Array:
    """σ² per pseudorange: the file's column or a·10^(−C/N0/10)/sin²(el)."""
    if which == "file":
        return ep.var_file
    if which == "cn0":
        return a * 10.0 ** (-ep.cn0 / 10.0)
    sin_el = np.sin(np.radians(np.clip(ep.el_deg, 5.0, 90.0)))
    return a * 10.0 ** (-ep.cn0 / 10.0) / sin_el**2


class PseudorangeModel:
    """Odometry-driven motion + whitened pseudoranges and odometry speed (module docstring)."""

    linear = False

    def __init__(self, ep: PrEpochs, sigma: Array, r0: Array, sigma_speed: float, sigma_acc: float,
                 q_clock: float, q_drift: float, q_vu: float) -> None:
        self.ep = ep
        self.sigma = np.where(np.isfinite(sigma), sigma, 1.0)
        self.r0 = r0
        lat0, lon0, _ = ecef_to_geodetic(r0)
        self.C_ne = rot_ecef_to_enu(lat0, lon0).T  # ENU -> ECEF
        self.ms = ep.rho.shape[1]
        self.m = self.ms + 1
        self.n = 9
        self.R0 = np.eye(self.m)
        self.sigma_speed = sigma_speed
        K1 = len(ep.t)
        dt = np.r_[0.0, np.diff(ep.t)]
        self.Fk = np.zeros((K1, 9, 9))
        self.Qk = np.zeros((K1, 9, 9))
        for k in range(K1):
            T = dt[k]
            th = ep.yaw_rate[k - 1] * T if k else 0.0  # CCW positive: turns (E, N) anticlockwise
            F = np.eye(9)
            F[0:3, 3:6] = T * np.eye(3)
            c, s = np.cos(th), np.sin(th)
            F[3:5, 3:5] = [[c, -s], [s, c]]
            F[5, 5] = np.exp(-T / 2.0)
            F[6, 8] = F[7, 8] = T
            # the position integrates the rotated velocity half-way (second order in ω T)
            c2, s2 = np.cos(th / 2), np.sin(th / 2)
            F[0:2, 3:5] = T * np.array([[c2, -s2], [s2, c2]])
            Q = np.zeros((9, 9))
            qa = np.array([sigma_acc**2, sigma_acc**2, q_vu])
            for i in range(3):
                Q[i, i] = qa[i] * T**3 / 3
                Q[i, i + 3] = Q[i + 3, i] = qa[i] * T**2 / 2
                Q[i + 3, i + 3] = qa[i] * T
            Q[6, 6] = Q[7, 7] = q_clock * T + q_drift * T**3 / 3
            Q[6, 7] = Q[7, 6] = q_drift * T**3 / 3
            Q[6, 8] = Q[8, 6] = Q[7, 8] = Q[8, 7] = q_drift * T**2 / 2
            Q[8, 8] = q_drift * T
            self.Fk[k], self.Qk[k] = F, Q
        self._sysmat = np.eye(2)[ep.sys_idx]  # (ms, 2)

    def F(self, k: int) -> Array:
        return self.Fk[k]

    def Q(self, k: int) -> Array:
        return self.Qk[k]

    def f(self, x: Array, k: int) -> Array:
        return x @ self.Fk[k].T

    def ecef(self, x: Array) -> Array:
        return self.r0 + x[:, 0:3] @ self.C_ne.T

    def h(self, x: Array, k: int) -> Array:
        r = self.ecef(x)
        rng, _ = geometric_range(self.ep.sat[k][None], r)
        pr = (rng + x[:, 6:8] @ self._sysmat.T) / self.sigma[k]
        sp = np.sqrt(x[:, 3] ** 2 + x[:, 4] ** 2 + 1e-6) / self.sigma_speed
        return np.concatenate([pr, sp[:, None]], axis=1)

    def H(self, x: Array, k: int) -> Array:
        B = x.shape[0]
        r = self.ecef(x)
        _, e = geometric_range(self.ep.sat[k][None], r)  # (B, ms, 3) ECEF unit vectors
        e_enu = e @ self.C_ne  # (B, ms, 3)
        H = np.zeros((B, self.m, 9))
        H[:, : self.ms, 0:3] = -e_enu / self.sigma[k][None, :, None]
        H[:, : self.ms, 6:8] = self._sysmat[None] / self.sigma[k][None, :, None]
        vh = np.sqrt(x[:, 3] ** 2 + x[:, 4] ** 2 + 1e-6)
        H[:, self.ms, 3] = x[:, 3] / vh / self.sigma_speed
        H[:, self.ms, 4] = x[:, 4] / vh / self.sigma_speed
        return H


@dataclass(frozen=True)
class SmartlocParams:
    epochs: int = param(0, lo=0, hi=100000, help="epochs to use (0: all 1371)")
    variance_model: str = param("cn0-elevation", choices=("cn0-elevation", "cn0", "file"),
                                help="pseudorange σ²: a·10^(−C/N0/10)/sin²(el), or the file's column")
    cn0_a: float = param(2.0e5, lo=1.0, hi=1e9, help="a of the C/N0 model (m²): σ = 2.5 m at 45 dBHz, zenith")
    sigma_speed: float = param(0.1, lo=1e-3, hi=100.0, help="odometry speed σ (m/s)")
    use_speed: bool = param(True, help="use the odometry speed as a measurement channel")
    sigma_acc: float = param(1.0, lo=1e-3, hi=100.0, help="horizontal white acceleration σ (m/s²/√Hz)")
    q_clock: float = param(1.0, lo=0.0, hi=1e6, help="clock-offset white noise PSD (m²/s)")
    q_drift: float = param(1.0, lo=0.0, hi=1e6, help="clock-drift random-walk PSD (m²/s³)")
    q_vu: float = param(
        0.01, lo=0.0, hi=100.0, help="vertical acceleration PSD (m²/s³): small = a car keeps its height")
    elevation_mask_deg: float = param(
        0.0, lo=0.0, hi=80.0, help="drop satellites below this elevation (deg)")
    cn0_mask_dbhz: float = param(0.0, lo=0.0, hi=60.0, help="drop pseudoranges below this C/N0 (dBHz)")
    data_dir: str = param("", help="data directory (default ../shared/data or $NAVLAB_DATA)", ui=False)


def _truth_clocks(ep: PrEpochs, sigma: Array) -> Array:
    rng, _ = geometric_range(ep.sat, ep.truth_ecef)
    res = ep.rho - rng
    cb = np.full((len(ep.t), 2), np.nan)
    for s in (0, 1):
        sel = ep.sys_idx == s
        with np.errstate(all="ignore"):
            r = np.where(np.isfinite(res[:, sel]), res[:, sel], np.nan)
            has = np.isfinite(r).any(axis=1)
            cb[has, s] = np.nanmedian(r[has], axis=1)
    # fill a constellation absent at an epoch from its neighbours
    for s in (0, 1):
        ok = np.isfinite(cb[:, s])
        cb[~ok, s] = np.interp(np.flatnonzero(~ok), np.flatnonzero(ok), cb[ok, s]) if ok.any() else 0.0
    return cb


@register_scenario
class SmartlocBerlin(Scenario):
    key = "smartloc-berlin"
    label = "Real urban pseudoranges: smartLoc Berlin"
    paper = "real data: smartLoc, TU Chemnitz (CC BY-SA 4.0)"
    summary = (
        "Real GPS + GLONASS pseudoranges from a car in Berlin's Potsdamer Platz canyon, with "
        "odometry and SPAN truth. Non-line-of-sight errors are heavy-tailed and mostly positive."
    )
    Params = SmartlocParams
    default_filters = ("wls", "ekf", "huber-kf", "vb-ekf", "chi2-kf", "student-t-kf", "irakf")
    default_runs = 1
    simulated = False
    linear = False  # nonlinear model (no probe run needed by the app)
    headline = ("hpos",)
    outlier_defaults: ClassVar[dict] = {"mixture": {"contamination": 0.0}}

    def simulate(
        self, schedule: Schedule, outliers: OutlierModel, runs: Sequence[int], seed: int
    ) -> ScenarioData:
        p = self.params
        ep = load_epochs(p.data_dir)
        K_all = len(ep.t) - 1
        K = K_all if not p.epochs else min(int(p.epochs), K_all)
        var = variance_model(ep, p.variance_model, p.cn0_a)[: K + 1]
        sig = np.sqrt(var)
        ep = PrEpochs(ep.t[: K + 1], ep.rho[: K + 1], ep.sat[: K + 1], ep.var_file[: K + 1],
                      ep.el_deg[: K + 1], ep.cn0[: K + 1], ep.sys_idx, ep.names,
                      ep.speed[: K + 1], ep.yaw_rate[: K + 1], ep.truth_ecef[: K + 1])
        r_fix, clk = robust_ls_fix(ep.rho[0], ep.sat[0], np.where(np.isfinite(sig[0]), sig[0], 1.0),
                                   ep.sys_idx)
        model = PseudorangeModel(ep, sig, r_fix, p.sigma_speed, p.sigma_acc, p.q_clock, p.q_drift, p.q_vu)
        ms, m = model.ms, model.m
        streams = [run_streams(seed, r) for r in runs]
        B = len(streams)
        # extra injected noise (schedule/outliers) in whitened units: the real errors stay
        std = schedule.std(np.ones(m), K)
        noise, var_inj, bias, mask = draw_measurement_noise(streams, std, outliers)
        used = np.isfinite(ep.rho)
        with np.errstate(invalid="ignore"):
            used &= (ep.el_deg >= p.elevation_mask_deg) & (ep.cn0 >= p.cn0_mask_dbhz)
        present = np.c_[used, np.full(K + 1, p.use_speed)]
        extra = np.where(mask, noise, 0.0)  # the nominal noise is real: inject only contamination
        z_clean = np.c_[ep.rho / model.sigma, ep.speed / p.sigma_speed]
        z = np.where(present[None], z_clean[None] + extra, np.nan)
        z[:, 0] = np.nan
        # truth
        enu = (ep.truth_ecef - r_fix) @ model.C_ne
        v = np.gradient(enu, ep.t, axis=0)
        cb = _truth_clocks(ep, sig)
        cd = np.gradient(cb[:, 0], ep.t)
        x_true = np.concatenate([enu, v, cb, cd[:, None]], axis=1)
        x0 = np.r_[np.zeros(3), np.zeros(3), clk, 0.0]
        P0 = np.diag([10.0**2] * 3 + [5.0**2, 5.0**2, 0.5**2] + [10.0**2] * 2 + [300.0**2])  # drift: ±1 ppm
        R_true = np.broadcast_to(np.ones((K + 1, m)), (B, K + 1, m)).copy()
        R_true[mask] = var_inj[mask]
        return ScenarioData(
            scenario=self.key,
            t=ep.t - ep.t[0],
            model=model,
            x_true=np.broadcast_to(x_true, (B, K + 1, 9)).copy(),
            z=z,
            R_true=R_true,
            R_schedule=np.ones((K + 1, m)),
            outlier_mask=mask & present[None],
            bias=bias,
            x0=np.broadcast_to(x0, (B, 9)).copy(),
            P0=P0,
            runs=np.asarray(runs),
            state_names=STATE_NAMES,
            channel_names=(*ep.names, "speed"),
            channel_units=("σ",) * ms + ("σ",),
            groups={
                "pos": MetricGroup((0, 1, 2), "m", "position (3-D)"),
                "hpos": MetricGroup((0, 1), "m", "horizontal position"),
                "vpos": MetricGroup((2,), "m", "vertical position"),
                "vel": MetricGroup((3, 4, 5), "m/s", "velocity"),
            },
            window=np.arange(K + 1) >= 1,
            has_truth=True,
            extras={
                "metrics": REAL_METRICS,
                "source": SMARTLOC_SOURCE,
                "recording": "smartloc_berlin_pp",
                "xy_idx": (0, 1),
                "sigma_m": sig,
                "t_abs_s": ep.t,
            },
        )
