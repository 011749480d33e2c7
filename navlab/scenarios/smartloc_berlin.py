"""Real urban pseudoranges ``smartloc-berlin``: smartLoc Berlin Potsdamer Platz (TU Chemnitz).

283 s, 1372 epochs at ≈5 Hz of GPS + GLONASS pseudoranges in a deep urban canyon, with odometry
(speed, yaw rate) and NovAtel SPAN ground truth. Non-line-of-sight reception makes the errors
heavy-tailed and mostly positive: the real test for robust and adaptive pseudorange filters.

Model (nonlinear, n = 8): x = [E, N, U (m, from a local origin), d_E, d_N (unit heading vector),
c·δt_GPS, c·δt_GLO (m), c·δṫ (m/s)].

* Motion: odometry dead reckoning, LINEAR (affine) given the odometry (so every filter, also
  those that only use the Jacobian F(k), propagates it exactly). Between epochs k−1 and k, with the mean
  odometry speed s̄ and yaw rate ω̄ (counter-clockwise positive) and θ = ω̄ T::

      d_k = Rot(θ) d_{k−1} ;  (E, N)_k = (E, N)_{k−1} + s̄ T sinc(θ/2) Rot(θ/2) d_{k−1} ;  U_k = U_{k−1}

  (the chord of the arc: exact for constant speed and yaw rate)

  The speed is an INPUT (the odometry's σ_speed enters Q along the track), so the heading d is
  the only horizontal motion state: a heading random walk (q_heading, rad²/s, covering the
  yaw-rate noise and bias) replaces the isotropic white acceleration of a velocity model, which
  had to let the cross-track velocity wander by the car's full along-track acceleration.
  q_pos adds a small position random walk (wheel slip, speed scale error); U is a random walk
  (q_height) unless the map prior (below) replaces it.
* Clock: ONE receiver oscillator: c·δt_GLO = c·δt_GPS + ISB, and both clock states share the
  clock's white-frequency (q_clock) and random-walk-frequency (q_drift) noise; only the
  inter-system bias ISB random-walks on its own, slowly (q_isb). (Two independent clock random
  walks let either constellation's clock absorb that constellation's NLOS errors.)
* Measurements, WHITENED (z_j/σ_j, h_j/σ_j: every filter uses the nominal R0 = I although σ_j
  changes per epoch; an adaptive filter's R̂ is then a variance MULTIPLIER relative to the model):
  - one channel per satellite, h_j(x) = ‖r_sat,j − r(x)‖ + ω_e/c (x_s y_r − y_s x_r) + c·δt_sys(j)
    (the second term is the Earth-rotation/Sagnac correction of satellite positions given at
    transmit time, RTKLIB's sign); σ_j from the variance model (default the C/N0-and-elevation
    model σ² = a·10^(−C/N0/10)/sin²(el); "file" uses the file's variance column, whose spread,
    5–14 m, is far narrower than that of the errors);
  - ``|d|``: the pseudo-measurement ‖d‖ = 1 (σ_heading_norm), present from ``heading_init_s`` on
    (before it the heading is estimated linearly from the first positions, so the filters need no
    initial heading);
  - ``height`` (only with ``height_aiding = "map"``): a pseudo-measurement, the antenna's
    ellipsoidal height = ``height_m`` ± ``sigma_height_m``.
* Height knowledge (``height_aiding``). In an urban canyon the vertical is the worst-observed
  direction: ranges that are too long (NLOS) come mostly from low satellites, which a receiver
  clock raised by the common part and a position raised by tens of metres explain best (without
  height knowledge every filter sits 20–35 m too high, and part of it leaks into the horizontal).
  A car on near-level streets knows its height from a map — common practice. The default
  ``height_m`` = 75 m is what a user reads off a map, not the truth: Potsdamer Platz lies ≈ 34 m
  above sea level (DHHN), the geoid there is ≈ 39.5 m above the WGS 84 ellipsoid (EGM2008) and a
  car-roof antenna is ≈ 1.5 m above the road.

  - ``"map-prior"`` (default): the knowledge sits in the MOTION model: U − U_ref is a first-order
    Gauss–Markov process (σ = ``sigma_height_m`` = 3 m: map error and slopes; correlation time
    ``tau_height_s`` = 30 s, ≈ 200 m of street), i.e. f(x) = F x + u with F_UU = φ = e^(−T/τ),
    u_U = (1 − φ) U_ref, Q_UU = σ²(1 − φ²); U_ref = height_m − the height of the local origin
    (the tangent plane's drop, E²+N²/2R ≈ 8 cm at 1 km, is neglected). Filters cannot adapt it
    away, and ``wls`` (no dynamics) stays the plain per-epoch reference.
  - ``"map"``: the same knowledge as a measurement channel. Adaptive filters then treat it like a
    sensor: because the state follows it, its residuals are small and VB/Sage–Husa estimates
    shrink its R̂ towards 0 (``hakf``: R̂_height 0.4 → 0.001 within 300 epochs), which turns it into
    a hard constraint; and a height pinned hard does not remove the NLOS error, it moves it — with
    the sky mostly to the south the fix is pushed north (first 400 epochs, ``huber-kf``: 7.6 m
    median horizontal error without height knowledge, 9.3 m with this channel at σ = 3 m).
  - ``"off"``: pseudoranges and odometry only.
* Truth: SPAN positions; heading from differenced positions (held while the car stands); clock
  "truth" = the per-constellation median of (ρ − range at the true position) — used only for NEES.
* Start: every filter starts at epoch 0 from a robust (Huber-reweighted, C/N0-weighted)
  least-squares fix of the epoch-0 pseudoranges (with the map height ± σ unless height aiding is
  off), an unknown heading (d = 0, P = I) and an unknown clock drift (±1 ppm).

Monte Carlo on real data: the pseudoranges are real, so every run sees the same errors; the
default is B = 1 and no injected contamination (``outlier_defaults`` sets the mixture's α to 0).
With ``--contamination α`` each run adds its own independent outliers (κσ, whitened units) on
top of the real ones — a stress test of the robust updates.

Filters that gate whole epochs (``chi2-kf`` in its paper mode) are at risk in this canyon:
nearly every epoch holds some non-line-of-sight range, so a rejected epoch lets the prediction
drift and later epochs may fail the gate too. With the former velocity model (white acceleration
1 m/s², two free-running clocks) the gate locked out for good (345 m median error); the
dead-reckoning model predicts well enough that it recovers (≈ 14 m). This scenario therefore
presets ``chi2-kf.per_channel=true`` (``filter_defaults``) — gating each satellite, the sensible
mode for ≈ 15 channels per epoch — which gives ≈ 10.5 m; ``--set chi2-kf.per_channel=false``
restores the whole-epoch gate.

vb-ekf (full inverse-Wishart R̂ over 20 channels) diverged here while its missing-channel rule
could make R̂ indefinite as satellites came and went; since the conditional-expectation rule
(``navlab/filters/vb_ekf.py``) it is the best filter here (≈ 8 m median; ≈ 9.3 m without height
knowledge).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import ClassVar

import numpy as np

from navlab.data.loaders import SMARTLOC_DIR, SMARTLOC_SOURCE
from navlab.errors import NavlabError
from navlab.ins.earth import OMEGA_IE_RADPS, ecef_to_geodetic, rot_ecef_to_enu
from navlab.linalg import Array
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
from navlab.scenarios.drive0708 import REAL_METRICS, fill_rows

C_LIGHT = 299792458.0
STATE_NAMES = ("E", "N", "U", "d_E", "d_N", "cb_GPS", "cb_GLO", "cd")  # Berlin: GPS + GLONASS
SYSTEM_NAMES = {1: "G", 2: "S", 4: "R", 8: "E", 16: "J", 32: "C"}
_EPS_NORM = 1e-12  # keeps ‖d‖ and its Jacobian finite at d = 0


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
    clock_names: tuple[str, ...] = ("GPS", "GLO")  # one receiver clock per system; sys_idx indexes it
    has_odometry: bool = True  # False: a constant-velocity model replaces the dead reckoning
    has_truth: bool = True
    name: str = "smartloc_berlin_pp"

    def cut(self, K: int) -> PrEpochs:
        """The first K+1 epochs."""
        import dataclasses

        per_epoch = ("t", "rho", "sat", "var_file", "el_deg", "cn0", "speed", "yaw_rate", "truth_ecef")
        return dataclasses.replace(self, **{f: getattr(self, f)[: K + 1] for f in per_epoch})


CLOCK_NAMES = {1: "GPS", 2: "SBAS", 4: "GLO", 8: "GAL", 16: "QZS", 32: "BDS"}


def _folder(data_dir: str):
    from navlab.data.loaders import SMARTLOC_DIR, data_root

    d = data_root(data_dir or None)
    return d / SMARTLOC_DIR if (d / SMARTLOC_DIR).is_dir() else d


def load_epochs(data_dir: str) -> PrEpochs:
    """The recording on epoch grids, cached while its files are unchanged."""
    d = _folder(data_dir)
    try:
        fp = tuple(sorted((p.name, p.stat().st_size, p.stat().st_mtime_ns) for p in d.iterdir()))
    except OSError:
        fp = ()
    return _load_epochs(data_dir, fp)


@lru_cache(maxsize=2)
def _load_epochs(data_dir: str, fingerprint: tuple) -> PrEpochs:
    from navlab.data.loaders import load_pseudoranges

    rec = load_pseudoranges(data_dir or None)
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
    systems = sorted({s for s, _ in keys})
    sys_idx = np.array([systems.index(s) for s, _ in keys])
    names = tuple(
        f"{SYSTEM_NAMES.get(s, '?')}{i:02d}" if s == 1 else f"{SYSTEM_NAMES.get(s, '?')}{i}" for s, i in keys
    )
    od = rec.odom
    if od is not None:
        speed = np.interp(t, od.t_s, od.speed_mps)
        yaw = np.interp(t, od.t_s, od.yaw_rate_radps)
    else:
        speed = yaw = np.zeros(K1)
    gt = rec.truth
    if gt is not None:
        truth = np.stack(
            [np.interp(t, gt.t_s, gt[c], left=np.nan, right=np.nan) for c in ("x_m", "y_m", "z_m")], -1
        )
    else:
        truth = np.full((K1, 3), np.nan)
    return PrEpochs(
        t,
        rho,
        sat,
        var,
        el,
        cn0,
        sys_idx,
        names,
        speed,
        yaw,
        truth,
        clock_names=tuple(CLOCK_NAMES[s] for s in systems),
        has_odometry=od is not None,
        has_truth=gt is not None and bool(np.isfinite(truth).all(axis=1).mean() > 0.5),
        name=rec.name,
    )


def geometric_range(sat: Array, r: Array) -> tuple[Array, Array]:
    """Range with the Sagnac correction and the unit vectors receiver→satellite (ECEF).

    sat (..., ms, 3), r (..., 3) -> range (..., ms), e (..., ms, 3).
    """
    d = sat - r[..., None, :]
    rng = np.linalg.norm(d, axis=-1)
    sagnac = OMEGA_IE_RADPS / C_LIGHT * (sat[..., 0] * r[..., None, 1] - sat[..., 1] * r[..., None, 0])
    return rng + sagnac, d / rng[..., None]


def robust_ls_fix(
    rho: Array,
    sat: Array,
    sigma: Array,
    sys_idx: Array,
    r0: Array | None = None,
    huber_k: float = 1.5,
    iters: int = 15,
    height: float | None = None,
    sigma_height: float = 1.0,
    n_sys: int | None = None,
) -> tuple[Array, Array]:
    """Huber-reweighted weighted least squares fix of one epoch: (r ECEF (3,), clocks (n_sys,)).

    One clock per satellite system (``sys_idx`` indexes them; ``n_sys`` default: the largest
    index + 1). With ``height`` the ellipsoidal height is pseudo-measured too (σ
    ``sigma_height``, never down-weighted), once the geometry has converged.
    """
    ok = np.isfinite(rho)
    n_sys = int(n_sys) if n_sys else int(np.max(sys_idx)) + 1
    r = np.zeros(3) if r0 is None else np.array(r0, float)
    clk = np.zeros(n_sys)
    w_h = np.ones(ok.sum())
    S = np.eye(n_sys)[sys_idx[ok]]
    has = S.sum(axis=0) > 0
    for it in range(iters):
        rng, e = geometric_range(sat[ok], r)
        res = rho[ok] - rng - S @ clk
        if it >= 4:  # Huber weights once the geometry has converged
            u = np.abs(res / sigma[ok])
            w_h = np.where(u <= huber_k, 1.0, huber_k / np.maximum(u, 1e-12))
        A = np.concatenate([-e, S], axis=1)[:, np.r_[True, True, True, has]]
        W = w_h / sigma[ok] ** 2
        if height is not None and it >= 4:
            h, up = geodetic_up(r)
            A = np.vstack([A, np.r_[up, np.zeros(int(has.sum()))]])
            res = np.r_[res, height - h]
            W = np.r_[W, 1.0 / sigma_height**2]
        N = A.T @ (A * W[:, None])
        dx = np.linalg.solve(N + 1e-9 * np.eye(N.shape[0]), A.T @ (W * res))
        r = r + dx[:3]
        clk[has] += dx[3:]
    return r, clk


#: C/N0 of the "elevation" model's zenith σ: with the C/N0 model's a, σ(45 dBHz, zenith) = 2.5 m.
REFERENCE_CN0_DBHZ = 45.0


def variance_model(ep: PrEpochs, which: str, a: float) -> Array:
    """σ² per pseudorange: the file's column, a·10^(−C/N0/10)/sin²(el), a·10^(−C/N0/10), or
    ("elevation", for files without C/N0) a·10^(−45/10)/sin²(el).
    """
    if which == "file":
        return ep.var_file
    if which == "cn0":
        return a * 10.0 ** (-ep.cn0 / 10.0)
    sin_el = np.sin(np.radians(np.clip(ep.el_deg, 5.0, 90.0)))
    if which == "elevation":
        return a * 10.0 ** (-REFERENCE_CN0_DBHZ / 10.0) / sin_el**2
    return a * 10.0 ** (-ep.cn0 / 10.0) / sin_el**2


def elevations_deg(sat: Array, r: Array) -> Array:
    """Elevation [deg] of satellites sat (..., ms, 3) seen from the ECEF point r (3,)."""
    _, up = geodetic_up(np.asarray(r, float))
    d = sat - r
    return np.degrees(np.arcsin(np.clip((d @ up) / np.linalg.norm(d, axis=-1), -1.0, 1.0)))


def _rot(th: Array) -> Array:
    """(..., 2, 2) rotation by th (counter-clockwise in the east/north plane)."""
    c, s = np.cos(th), np.sin(th)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def geodetic_up(r: Array) -> tuple[Array, Array]:
    """Ellipsoidal height (...,) and the local up unit vector (..., 3) of ECEF points r (..., 3)."""
    lat, lon, h = ecef_to_geodetic(r)
    up = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1)
    return h, up


class PseudorangeModel:
    """Odometry dead reckoning + whitened pseudoranges, ‖d‖ = 1 and height (module docstring).

    State: E, N, U, d_E, d_N, one clock per satellite system (``ep.clock_names``), clock drift.
    Without odometry (``ep.has_odometry`` false) d is the horizontal VELOCITY of a
    constant-velocity model (white acceleration, PSD ``q_accel``) and there is no ‖d‖ channel.
    """

    linear = False

    def __init__(
        self,
        ep: PrEpochs,
        sigma: Array,
        r0: Array,
        *,
        sigma_speed: float,
        q_heading: float,
        q_pos: float,
        q_height: float,
        q_clock: float,
        q_drift: float,
        q_isb: float,
        sigma_norm: float,
        sigma_height: float | None,
        height_prior: tuple[float, float, float] | None = None,
        q_accel: float = 1.0,
    ) -> None:
        self.ep = ep
        self.sigma = np.where(np.isfinite(sigma), sigma, 1.0)
        self.r0 = r0
        lat0, lon0, _ = ecef_to_geodetic(r0)
        self.C_ne = rot_ecef_to_enu(lat0, lon0).T  # ENU -> ECEF
        self.ms = ep.rho.shape[1]
        self.sigma_norm = sigma_norm
        self.sigma_height = sigma_height
        self.odometry = bool(ep.has_odometry)
        self.S = S = len(ep.clock_names)
        self.m = self.ms + int(self.odometry) + (sigma_height is not None)
        self.n = n = 6 + S
        c = slice(5, 5 + S)  # clock states; 5 + S is the drift
        self.R0 = np.eye(self.m)
        # the pseudoranges' errors are one-sided (NLOS: too long); ‖d‖ and height are not
        self.positive_skew = np.arange(self.m) < self.ms
        K1 = len(ep.t)
        T = np.r_[0.0, np.diff(ep.t)]
        F = np.broadcast_to(np.eye(n), (K1, n, n)).copy()
        Q = np.zeros((K1, n, n))
        if self.odometry:
            s_bar = np.r_[0.0, 0.5 * (ep.speed[1:] + ep.speed[:-1])]
            w_bar = np.r_[0.0, 0.5 * (ep.yaw_rate[1:] + ep.yaw_rate[:-1])]
            th = w_bar * T
            F[:, 3:5, 3:5] = _rot(th)
            # the chord of the arc: length s̄T·sin(θ/2)/(θ/2), direction turned by θ/2
            F[:, 0:2, 3:5] = (s_bar * T * np.sinc(th / (2 * np.pi)))[:, None, None] * _rot(th / 2)
            Q[:, 0, 0] = Q[:, 1, 1] = (sigma_speed * T) ** 2 + q_pos * T
            Q[:, 3, 3] = Q[:, 4, 4] = q_heading * T
        else:  # constant velocity: (E, N)_k = (E, N)_{k−1} + T v ; v random walk (white acceleration)
            F[:, 0:2, 3:5] = T[:, None, None] * np.eye(2)
            Q[:, 0, 0] = Q[:, 1, 1] = q_accel * T**3 / 3 + q_pos * T
            Q[:, 0, 3] = Q[:, 3, 0] = Q[:, 1, 4] = Q[:, 4, 1] = q_accel * T**2 / 2
            Q[:, 3, 3] = Q[:, 4, 4] = q_accel * T
        Q[:, 2, 2] = q_height * T
        F[:, c, 5 + S] = T[:, None]
        # one oscillator: every system's clock = the common clock b + its ISB, drift ḃ
        b = q_clock * T + q_drift * T**3 / 3
        Q[:, c, c] = b[:, None, None]
        for i in range(1, S):
            Q[:, 5 + i, 5 + i] += q_isb * T
        Q[:, c, 5 + S] = (q_drift * T**2 / 2)[:, None]
        Q[:, 5 + S, c] = (q_drift * T**2 / 2)[:, None]
        Q[:, 5 + S, 5 + S] = q_drift * T
        self.uk = np.zeros((K1, n))
        if height_prior is not None:  # U − U_ref: Gauss–Markov (σ, τ) in the dynamics
            u_ref, sig_h, tau = height_prior
            phi = np.exp(-T / tau)
            F[:, 2, 2] = phi
            Q[:, 2, 2] = sig_h**2 * (1.0 - phi**2)
            self.uk[:, 2] = (1.0 - phi) * u_ref
        self.Fk, self.Qk = F, Q
        self._sysmat = np.eye(S)[ep.sys_idx]  # (ms, S)

    def F(self, k: int) -> Array:
        return self.Fk[k]

    def Q(self, k: int) -> Array:
        return self.Qk[k]

    def f(self, x: Array, k: int) -> Array:
        return x @ self.Fk[k].T + self.uk[k]

    def ecef(self, x: Array) -> Array:
        return self.r0 + x[:, 0:3] @ self.C_ne.T

    def h(self, x: Array, k: int) -> Array:
        r = self.ecef(x)
        rng, _ = geometric_range(self.ep.sat[k][None], r)
        pr = (rng + x[:, 5 : 5 + self.S] @ self._sysmat.T) / self.sigma[k]
        cols = [pr]
        if self.odometry:
            cols.append(np.sqrt(x[:, 3:4] ** 2 + x[:, 4:5] ** 2 + _EPS_NORM) / self.sigma_norm)
        if self.sigma_height is not None:
            cols.append(geodetic_up(r)[0][:, None] / self.sigma_height)
        return np.concatenate(cols, axis=1)

    def H(self, x: Array, k: int) -> Array:
        B = x.shape[0]
        r = self.ecef(x)
        _, e = geometric_range(self.ep.sat[k][None], r)  # (B, ms, 3) ECEF unit vectors
        e_enu = e @ self.C_ne  # (B, ms, 3)
        ms = self.ms
        H = np.zeros((B, self.m, self.n))
        H[:, :ms, 0:3] = -e_enu / self.sigma[k][None, :, None]
        H[:, :ms, 5 : 5 + self.S] = self._sysmat[None] / self.sigma[k][None, :, None]
        j = ms
        if self.odometry:
            nd = np.sqrt(x[:, 3] ** 2 + x[:, 4] ** 2 + _EPS_NORM)
            H[:, j, 3:5] = x[:, 3:5] / nd[:, None] / self.sigma_norm
            j += 1
        if self.sigma_height is not None:
            H[:, j, 0:3] = geodetic_up(r)[1] @ self.C_ne / self.sigma_height
        return H


@dataclass(frozen=True)
class SmartlocParams:
    epochs: int = param(0, lo=0, hi=MAX_EPOCHS, help="epochs to use (0: all 1371)")
    variance_model: str = param(
        "cn0-elevation",
        choices=("cn0-elevation", "cn0", "elevation", "file"),
        help="pseudorange σ²: a·10^(−C/N0/10)/sin²(el), a·10^(−C/N0/10), a·10^(−4.5)/sin²(el) (no C/N0), "
        "or the file's column",
    )
    cn0_a: float = param(2.0e5, lo=1.0, hi=1e9, help="a of the C/N0 model (m²): σ = 2.5 m at 45 dBHz, zenith")
    height_aiding: str = param(
        "map-prior",
        choices=("map-prior", "map", "off"),
        help="'map-prior': the height deviates from height_m as a Gauss–Markov process in the "
        "motion model; 'map': a pseudo-measurement height = height_m; 'off': no height knowledge",
    )
    height_m: float = param(
        75.0,
        lo=-500.0,
        hi=9000.0,
        help="terrain height from a map, WGS 84 ellipsoidal, antenna (m): Potsdamer Platz ≈ 34 m "
        "above sea level + geoid 39.5 m + antenna 1.5 m",
    )
    sigma_height_m: float = param(
        3.0, lo=0.01, hi=1000.0, help="σ of the antenna height about height_m (m): map error + slopes"
    )
    tau_height_s: float = param(
        30.0, lo=0.1, hi=1e6, help="'map-prior': correlation time of the height deviation (s)"
    )
    sigma_speed: float = param(
        0.05, lo=1e-3, hi=100.0, help="odometry speed σ (m/s; the file's covariance column: 0.05)"
    )
    q_heading: float = param(
        1e-4,
        lo=0.0,
        hi=10.0,
        help="heading random-walk PSD (rad²/s): the file's yaw-rate σ (2e-3 rad/s) held ≈ 25 s",
    )
    q_pos: float = param(
        0.01, lo=0.0, hi=100.0, help="horizontal position random-walk PSD (m²/s): slip, speed scale"
    )
    q_height: float = param(
        0.05, lo=0.0, hi=100.0, help="height random-walk PSD (m²/s; not with the map prior)"
    )
    q_accel: float = param(
        1.0,
        lo=0.0,
        hi=1e4,
        help="without odometry: white-acceleration PSD of the constant-velocity model (m²/s³)",
    )
    q_clock: float = param(0.1, lo=0.0, hi=1e6, help="clock white-frequency PSD (m²/s)")
    q_drift: float = param(0.1, lo=0.0, hi=1e6, help="clock random-walk-frequency PSD (m²/s³)")
    q_isb: float = param(1e-3, lo=0.0, hi=1e6, help="GPS–GLONASS inter-system bias random-walk PSD (m²/s)")
    sigma_heading_norm: float = param(
        0.02, lo=1e-4, hi=10.0, help="σ of the pseudo-measurement ‖d‖ = 1 (unit heading vector)"
    )
    heading_init_s: float = param(
        3.0, lo=0.0, hi=100.0, help="seconds before ‖d‖ = 1 is applied (the heading forms first)"
    )
    elevation_mask_deg: float = param(0.0, lo=0.0, hi=80.0, help="drop satellites below this elevation (deg)")
    cn0_mask_dbhz: float = param(0.0, lo=0.0, hi=60.0, help="drop pseudoranges below this C/N0 (dBHz)")
    data_dir: str = param(
        "",
        help="data directory (default ../shared/data or $NAVLAB_DATA), a smartLoc sequence's folder or a "
        "folder with pseudoranges.csv (generic format)",
        ui=False,
    )


def _truth_clocks(ep: PrEpochs) -> Array:
    """Clock "truth" per system: the median of (ρ − range at the true position) over its satellites."""
    S = len(ep.clock_names)
    rng, _ = geometric_range(ep.sat, ep.truth_ecef)
    res = ep.rho - rng
    cb = np.full((len(ep.t), S), np.nan)
    for s in range(S):
        sel = ep.sys_idx == s
        r = res[:, sel]
        has = np.isfinite(r).any(axis=1)
        if has.any():
            cb[has, s] = np.nanmedian(r[has], axis=1)
    # fill a constellation absent at an epoch from its neighbours
    for s in range(S):
        ok = np.isfinite(cb[:, s])
        cb[~ok, s] = np.interp(np.flatnonzero(~ok), np.flatnonzero(ok), cb[ok, s]) if ok.any() else 0.0
    return cb


def _truth_heading(enu: Array, t: Array) -> Array:
    """Unit heading (east, north) of the true track; held over stands (speed < 0.5 m/s)."""
    v = np.gradient(enu[:, 0:2], t, axis=0)
    sp = np.hypot(v[:, 0], v[:, 1])
    moving = sp > 0.5
    if not moving.any():
        return np.tile([0.0, 1.0], (len(t), 1))
    idx = np.where(moving, np.arange(len(t)), -1)
    idx = np.maximum.accumulate(idx)
    idx[idx < 0] = np.flatnonzero(moving)[0]
    return v[idx] / sp[idx, None]


def _check_height(ep: PrEpochs, p: SmartlocParams) -> None:
    """Refuse Berlin's map height (the default ``height_m``) for another recording."""
    if ep.name != SMARTLOC_DIR and p.height_aiding != "off" and p.height_m == 75.0:
        raise NavlabError(
            f"height_m = {p.height_m:g} m is the map height of Berlin's Potsdamer Platz; for "
            f"{ep.name} give your street's ellipsoidal antenna height (scenario.height_m) or set "
            "scenario.height_aiding=off"
        )


def _with_elevations(ep: PrEpochs, notes: list[str]) -> PrEpochs:
    """``ep`` with the elevations the file lacks computed from a first least-squares fix."""
    if np.isfinite(ep.el_deg[np.isfinite(ep.rho)]).all():
        return ep
    r_rough, _ = robust_ls_fix(
        ep.rho[0], ep.sat[0], np.ones(ep.rho.shape[1]), ep.sys_idx, n_sys=len(ep.clock_names)
    )
    el = np.where(np.isfinite(ep.el_deg), ep.el_deg, elevations_deg(ep.sat, r_rough))
    notes.append("elevations computed from a first least-squares fix (the file has none)")
    return replace(ep, el_deg=el)


def _variance_model_used(ep: PrEpochs, p: SmartlocParams, notes: list[str]) -> str:
    """The variance model asked for, or the one the file's columns allow (a note says so)."""
    vm = p.variance_model
    has_cn0 = np.isfinite(ep.cn0[np.isfinite(ep.rho)]).all()
    if vm in ("cn0-elevation", "cn0") and not has_cn0:
        vm = "file" if np.isfinite(ep.var_file[np.isfinite(ep.rho)]).all() else "elevation"
        notes.append(f"variance model '{p.variance_model}' needs C/N0, which the file lacks: '{vm}' used")
    if vm == "file" and not np.isfinite(ep.var_file[np.isfinite(ep.rho)]).all():
        raise NavlabError(
            "variance_model 'file' needs the var_m2 column; choose 'cn0-elevation' or 'elevation'"
        )
    return vm


def _used_pseudoranges(ep: PrEpochs, p: SmartlocParams) -> Array:
    """(K+1, m) the pseudoranges present and above the elevation and C/N0 masks."""
    used = np.isfinite(ep.rho)
    with np.errstate(invalid="ignore"):
        used &= (ep.el_deg >= p.elevation_mask_deg) & ~(ep.cn0 < p.cn0_mask_dbhz)
    systems = len(set(ep.sys_idx[used[0]].tolist()))
    need = 3 + max(systems, 1) - (p.height_aiding != "off")  # position, a clock per system − height
    if used[0].sum() < need:
        masks = p.elevation_mask_deg > 0 or p.cn0_mask_dbhz > 0
        raise NavlabError(
            f"{int(used[0].sum())} pseudorange(s) at the first epoch"
            + (
                f" pass the masks (elevation ≥ {p.elevation_mask_deg:g}°, C/N0 ≥ {p.cn0_mask_dbhz:g} dBHz)"
                if masks
                else ""
            )
            + f"; the first fix needs {need}: "
            + (
                "lower scenario.elevation_mask_deg or scenario.cn0_mask_dbhz"
                if masks
                else "start the recording later"
            )
        )
    return used


def _first_fix(ep: PrEpochs, p: SmartlocParams, used: Array, sig: Array) -> tuple[Array, Array]:
    """Robust least-squares fix at epoch 0 (with the map height unless height aiding is off): (r, clocks)."""
    return robust_ls_fix(
        np.where(used[0], ep.rho[0], np.nan),
        ep.sat[0],
        np.where(np.isfinite(sig[0]), sig[0], 1.0),
        ep.sys_idx,
        height=None if p.height_aiding == "off" else p.height_m,
        sigma_height=p.sigma_height_m,
        n_sys=len(ep.clock_names),
    )


def _pseudorange_model(ep: PrEpochs, p: SmartlocParams, sig: Array, r_fix: Array) -> PseudorangeModel:
    """The pseudorange model with the scenario's noise and height aiding, about the origin ``r_fix``."""
    return PseudorangeModel(
        ep,
        sig,
        r_fix,
        sigma_speed=p.sigma_speed,
        q_heading=p.q_heading,
        q_pos=p.q_pos,
        q_height=p.q_height,
        q_clock=p.q_clock,
        q_drift=p.q_drift,
        q_isb=p.q_isb,
        sigma_norm=p.sigma_heading_norm,
        sigma_height=p.sigma_height_m if p.height_aiding == "map" else None,
        height_prior=None
        if p.height_aiding != "map-prior"
        else (p.height_m - float(ecef_to_geodetic(r_fix)[2]), p.sigma_height_m, p.tau_height_s),
        q_accel=p.q_accel,
    )


def _summary_note(ep: PrEpochs, p: SmartlocParams, model: PseudorangeModel, used: Array, vm: str) -> str:
    """One sentence on the pseudoranges used, the clocks, σ, the motion model and the height."""
    K = len(ep.t) - 1
    return (
        f"pseudoranges: {int(used.sum())} of {int(np.isfinite(ep.rho).sum())} used over {K} epochs; "
        f"{model.S} system(s) ({', '.join(ep.clock_names)}), each with its own receiver clock on one "
        f"oscillator; σ from the '{vm}' variance model; motion: "
        + ("odometry dead reckoning" if model.odometry else "constant velocity (no odometry in the files)")
        + f"; height: {p.height_aiding}"
        + ("" if ep.has_truth else "; no truth: errors cannot be computed")
    )


def _clean_z(ep: PrEpochs, p: SmartlocParams, model: PseudorangeModel, used: Array) -> tuple[Array, Array]:
    """Whitened measurements of every channel and which are present: (z (K+1, m), present (K+1, m)).

    Channels: the satellites, then ‖d‖ = 1 (with odometry, from ``heading_init_s`` on), then the
    map height (``height_aiding = "map"``).
    """
    K = len(ep.t) - 1
    t_rel = ep.t - ep.t[0]
    cols_present = [used]
    cols_z = [ep.rho / model.sigma]
    if model.odometry:
        cols_present.append((t_rel >= p.heading_init_s)[:, None])
        cols_z.append(np.full((K + 1, 1), 1.0 / p.sigma_heading_norm))
    if p.height_aiding == "map":
        cols_present.append(np.ones((K + 1, 1), dtype=bool))
        cols_z.append(np.full((K + 1, 1), p.height_m / p.sigma_height_m))
    return np.concatenate(cols_z, axis=1), np.concatenate(cols_present, axis=1)


def _true_states(ep: PrEpochs, model: PseudorangeModel, r_fix: Array) -> Array:
    """(K+1, n) the truth of every state (NaN without a truth file)."""
    if not ep.has_truth:
        return np.full((len(ep.t), model.n), np.nan)
    enu = (ep.truth_ecef - r_fix) @ model.C_ne
    # the heading state, or (constant-velocity model) the velocity
    d_true = _truth_heading(enu, ep.t) if model.odometry else np.gradient(enu[:, 0:2], ep.t, axis=0)
    cb = _truth_clocks(ep)
    cd = np.gradient(cb[:, 0], ep.t)
    return fill_rows(np.concatenate([enu, d_true, cb, cd[:, None]], axis=1))


def _prior(model: PseudorangeModel, clk: Array) -> tuple[Array, Array]:
    """x0 (at the first fix, with its clocks) and P0."""
    x0 = np.r_[np.zeros(3), np.zeros(2), clk, 0.0]
    P0 = np.diag(
        [10.0**2] * 3 + ([1.0, 1.0] if model.odometry else [15.0**2] * 2) + [10.0**2] * model.S + [300.0**2]
    )  # heading unknown (or a city speed, ≤ 15 m/s, without odometry); drift: ±1 ppm
    return x0, P0


def _channel_and_state_names(
    ep: PrEpochs, model: PseudorangeModel, aid_h: bool
) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The channel names and the state names."""
    names = (*ep.names, *(("|d|",) if model.odometry else ())) + (("height",) if aid_h else ())
    state_names = ("E", "N", "U", *(("d_E", "d_N") if model.odometry else ("v_E", "v_N")))
    state_names += (*(f"cb_{c}" for c in ep.clock_names), "cd")
    return names, state_names


def _metric_groups(odometry: bool) -> dict[str, MetricGroup]:
    """Position (3-D, horizontal, vertical) and the heading vector or, without odometry, the velocity."""
    return {
        "pos": MetricGroup((0, 1, 2), "m", "position (3-D)"),
        "hpos": MetricGroup((0, 1), "m", "horizontal position"),
        "vpos": MetricGroup((2,), "m", "vertical position"),
        "heading": MetricGroup((3, 4), "", "unit heading vector")
        if odometry
        else MetricGroup((3, 4), "m/s", "horizontal velocity"),
    }


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
    # one epoch holds 10–20 satellites: a whole-epoch χ² gate throws the clean ones away with a
    # reflected one (and locks out once it rejects a few epochs in a row); gate each satellite
    filter_defaults: ClassVar[dict] = {"chi2-kf": {"per_channel": True}}

    def simulate(
        self, schedule: Schedule, outliers: OutlierModel, runs: Sequence[int], seed: int
    ) -> ScenarioData:
        p = self.params
        ep = load_epochs(p.data_dir)
        K_all = len(ep.t) - 1
        K = K_all if not p.epochs else min(int(p.epochs), K_all)
        ep = ep.cut(K)
        notes = []
        _check_height(ep, p)
        ep = _with_elevations(ep, notes)
        vm = _variance_model_used(ep, p, notes)
        sig = np.sqrt(variance_model(ep, vm, p.cn0_a))
        used = _used_pseudoranges(ep, p)
        r_fix, clk = _first_fix(ep, p, used, sig)
        model = _pseudorange_model(ep, p, sig, r_fix)
        notes.append(_summary_note(ep, p, model, used, vm))
        m, n = model.m, model.n
        streams = run_streams(seed, runs)
        B = len(streams)
        # extra injected noise (schedule/outliers) in whitened units: the real errors stay
        std = schedule.std(np.ones(m), K)
        noise, var_inj, bias, mask = draw_measurement_noise(streams, std, outliers)
        z_clean, present = _clean_z(ep, p, model, used)
        extra = np.where(mask, noise, 0.0)  # the nominal noise is real: inject only contamination
        z = np.where(present[None], z_clean[None] + extra, np.nan)
        z[:, 0] = np.nan
        x0, P0 = _prior(model, clk)
        R_true = np.broadcast_to(np.ones((K + 1, m)), (B, K + 1, m)).copy()
        R_true[mask] = var_inj[mask]
        names, state_names = _channel_and_state_names(ep, model, p.height_aiding == "map")
        return ScenarioData(
            scenario=self.key,
            t=ep.t - ep.t[0],
            model=model,
            x_true=np.broadcast_to(_true_states(ep, model, r_fix), (B, K + 1, n)).copy(),
            z=z,
            # urban pseudorange errors reach ~100 m per epoch (WLS): a filter kilometres off has lost it
            divergence_bound=1000.0,
            R_true=R_true,
            R_schedule=np.ones((K + 1, m)),
            outlier_mask=mask & present[None],
            bias=bias,
            x0=np.broadcast_to(x0, (B, n)).copy(),
            P0=P0,
            runs=np.asarray(runs),
            state_names=state_names,
            channel_names=names,
            channel_units=("σ",) * len(names),
            groups=_metric_groups(model.odometry),
            window=(np.arange(K + 1) >= 1) & (np.isfinite(ep.truth_ecef).all(axis=1) | (not ep.has_truth)),
            has_truth=bool(ep.has_truth),
            extras={
                "metrics": REAL_METRICS,
                "source": SMARTLOC_SOURCE if ep.name == SMARTLOC_DIR else f"{ep.name} (your pseudoranges)",
                "recording": ep.name,
                "notes": notes,
                "xy_idx": (0, 1),
                "sigma_m": sig,
                "t_abs_s": ep.t,
            },
        )


@dataclass(frozen=True)
class OwnPseudorangesParams(SmartlocParams):
    epochs: int = param(0, lo=0, hi=MAX_EPOCHS, help="epochs to use (0: all)")
    height_aiding: str = param(
        "off",
        choices=("map-prior", "map", "off"),
        help="'off': pseudoranges (and odometry) only; 'map-prior' / 'map': your street's height_m as a "
        "Gauss–Markov prior / a pseudo-measurement",
    )
    height_m: float = param(
        0.0,
        lo=-500.0,
        hi=9000.0,
        help="your street's WGS 84 ellipsoidal antenna height (m) for height aiding",
    )
    data_dir: str = param(
        "",
        help="a folder with pseudoranges.csv[, odometry.csv, truth.csv] or one smartLoc sequence",
        ui=False,
    )


@register_scenario
class OwnPseudoranges(SmartlocBerlin):
    key = "own-pseudoranges"
    label = "Your own pseudoranges (generic CSV or smartLoc format)"
    paper = "your data (generic navlab pseudorange CSV / smartLoc)"
    summary = (
        "Your own pseudoranges (pseudoranges.csv[, odometry.csv, truth.csv], or a smartLoc sequence): "
        "one receiver clock per satellite system, odometry dead reckoning or a constant-velocity model."
    )
    Params = OwnPseudorangesParams
    #: needs a folder of the user's files (data_dir); see OwnDrive.user_data
    user_data: ClassVar[bool] = True

    def simulate(self, schedule, outliers, runs, seed):
        if not self.params.data_dir:
            from navlab.errors import NavlabError

            raise NavlabError(
                "own-pseudoranges needs a folder: set scenario.data_dir=FOLDER holding pseudoranges.csv "
                "(docs/data.md, 'Your own pseudoranges') or one smartLoc *_Input.txt"
            )
        if self.params.height_aiding != "off" and self.params.height_m == 0.0:
            from navlab.errors import NavlabError

            raise NavlabError("height aiding needs your street's ellipsoidal height: set scenario.height_m")
        return super().simulate(schedule, outliers, runs, seed)
