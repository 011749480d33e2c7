"""Batched strapdown INS mechanisation in the local-level ENU frame, and its error model.

Frames and units
----------------
* navigation frame ``n`` = ENU; body frame ``b`` = the IMU's own axes (whatever they are:
  the mechanisation never assumes RFU; the attitude angle helpers in `navlab.ins.earth`
  assume RFU, so rotate with a body-to-vehicle matrix first if you want car angles);
* position: geodetic latitude / longitude [rad] and ellipsoidal height [m];
* velocity ``v_enu_mps`` [m/s]; attitude ``C_bn`` = ``C_b^n`` (3x3);
* IMU samples: specific force ``f_b_mps2`` [m/s^2] and angular rate ``w_b_radps`` [rad/s].

Every state array carries a leading batch axis ``B``: a filter owns B independent INS
solutions (Monte Carlo runs, or filter variants) that are all advanced by ONE Python loop
over IMU samples.

Error-state sign convention (ALGORITHMS.md section 8.0, PSINS)
-------------------------------------------------------------
error = INS - truth. The 15-state error vector is

``x = [phi (3, ENU, rad), dv (3, ENU, m/s), dp (3, metres N, E, U), eps (3, gyro bias,
body, rad/s), nabla (3, accel bias, body, m/s^2)]``

with ``C_b^n(INS) = (I - [phi x]) C_b^n(true)``, ``v(INS) = v(true) + dv``,
``dp_N = (lat_INS - lat_true) R_Mh``, ``dp_E = (lon_INS - lon_true) R_Nh cos L``,
``dp_U = h_INS - h_true`` and ``w_meas = w_true + eps``, ``f_meas = f_true + nabla``.
`apply_correction` removes an estimated error from the INS (closed loop) and adds the
estimated sensor errors to the running bias estimates, after which the filter must reset
those states to zero.

Note on position order: the §8.0 state orders position as (N, E, U) metres, while the
velocity and attitude blocks are (E, N, U).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from navlab.errors import NavlabError
from navlab.ins.earth import (
    GAMMA_E_MPS2 as _GE,
)
from navlab.ins.earth import (
    GAMMA_P_MPS2 as _GP,
)
from navlab.ins.earth import (
    OMEGA_IE_RADPS as _WIE,
)
from navlab.ins.earth import (
    WGS84_A_M as _A,
)
from navlab.ins.earth import (
    WGS84_B_M as _B,
)
from navlab.ins.earth import (
    WGS84_E2 as _E2,
)
from navlab.ins.earth import (
    WGS84_F as _F,
)
from navlab.ins.earth import (
    WGS84_GM_M3PS2 as _GM,
)
from navlab.ins.earth import (
    earth_rate_enu,
    normal_gravity,
    orthonormalize,
    radii,
    rotvec_to_dcm,
    skew,
    transport_rate_enu,
)
from navlab.jit import Kernel, carray

__all__ = [
    "ImuBlock",
    "InsState",
    "apply_correction",
    "discretise",
    "error_model_FG",
    "init_state",
    "mechanise_step",
    "propagate_block",
]


@dataclass(frozen=True)
class InsState:
    """B strapdown navigation solutions (all arrays have leading axis B).

    Attributes
    ----------
    lat_rad, lon_rad, h_m : numpy.ndarray
        Geodetic latitude, longitude [rad] and ellipsoidal height [m], shape (B,).
    v_enu_mps : numpy.ndarray
        Velocity east, north, up [m/s], shape (B, 3).
    C_bn : numpy.ndarray
        Attitude ``C_b^n`` (body to ENU), shape (B, 3, 3).
    bias_g_radps : numpy.ndarray
        Current gyro bias estimate [rad/s] subtracted from every gyro sample, (B, 3).
    bias_a_mps2 : numpy.ndarray
        Current accelerometer bias estimate [m/s^2] subtracted from every sample, (B, 3).
    t_s : float
        Time of the solution [s] (common to the batch).
    """

    lat_rad: np.ndarray
    lon_rad: np.ndarray
    h_m: np.ndarray
    v_enu_mps: np.ndarray
    C_bn: np.ndarray
    bias_g_radps: np.ndarray
    bias_a_mps2: np.ndarray
    t_s: float = 0.0

    @property
    def B(self) -> int:
        """Batch size."""
        return int(self.lat_rad.shape[0])


@dataclass(frozen=True)
class ImuBlock:
    """What happened over one block of IMU samples (between two aiding epochs).

    Attributes
    ----------
    dt_s : float
        Block length [s].
    n_samples : int
        IMU samples integrated.
    f_b_mean_mps2, w_b_mean_radps : numpy.ndarray
        Bias-corrected mean specific force [m/s^2] and angular rate [rad/s] in body, (B, 3).
    f_n_mean_mps2 : numpy.ndarray
        Mean specific force rotated to ENU [m/s^2], (B, 3): the ``f^n`` of the error-state F.
    """

    dt_s: float
    n_samples: int
    f_b_mean_mps2: np.ndarray
    w_b_mean_radps: np.ndarray
    f_n_mean_mps2: np.ndarray


def _batch(a, B, shape, name):
    a = np.asarray(a, dtype=float)
    out = np.broadcast_to(a, (B, *shape)).copy() if a.shape != (B, *shape) else a.copy()
    if not np.all(np.isfinite(out)):
        raise NavlabError(f"INS initial {name} contains NaN/inf; give finite values.")
    return out


def init_state(lat_rad, lon_rad, h_m, v_enu_mps, C_bn, B=1, bias_g_radps=0.0, bias_a_mps2=0.0, t_s=0.0):
    """Build an `InsState` for B solutions, broadcasting scalars / single vectors over B.

    Parameters
    ----------
    lat_rad, lon_rad, h_m : float or array_like (B,)
        Initial position [rad, rad, m].
    v_enu_mps : array_like (3,) or (B, 3)
        Initial ENU velocity [m/s].
    C_bn : array_like (3, 3) or (B, 3, 3)
        Initial attitude ``C_b^n``.
    B : int
        Batch size (ignored if a batched argument fixes it).
    bias_g_radps, bias_a_mps2 : array_like, optional
        Initial sensor bias estimates [rad/s], [m/s^2].
    t_s : float
        Initial time [s].

    Returns
    -------
    InsState
    """
    for a in (lat_rad, lon_rad, h_m):
        if np.ndim(a) == 1:
            B = len(a)
    if np.ndim(C_bn) == 3:
        B = np.shape(C_bn)[0]
    return InsState(
        lat_rad=_batch(lat_rad, B, (), "latitude"),
        lon_rad=_batch(lon_rad, B, (), "longitude"),
        h_m=_batch(h_m, B, (), "height"),
        v_enu_mps=_batch(v_enu_mps, B, (3,), "velocity"),
        C_bn=_batch(C_bn, B, (3, 3), "attitude"),
        bias_g_radps=_batch(bias_g_radps, B, (3,), "gyro bias"),
        bias_a_mps2=_batch(bias_a_mps2, B, (3,), "accelerometer bias"),
        t_s=float(t_s),
    )


_LEVI = np.zeros((3, 9))
_PERM = ((0, 1, 2, 1), (1, 2, 0, 1), (2, 0, 1, 1), (0, 2, 1, -1), (2, 1, 0, -1), (1, 0, 2, -1))
for _i, _j, _k, _sgn in _PERM:
    _LEVI[_k, 3 * _i + _j] = -_sgn  # [phi x]_ij = -eps_ijk phi_k
_I3 = np.eye(3)


def _expm_so3(phi):
    """``exp([phi x])`` for (B, 3) rotation vectors; Taylor series below 0.1 rad (error < 1e-16)."""
    a2 = np.einsum("bi,bi->b", phi, phi)[:, None, None]
    if a2.max(initial=0.0) < 1e-2:
        s1 = 1.0 - a2 / 6.0 * (1.0 - a2 / 20.0 * (1.0 - a2 / 42.0))
        s2 = 0.5 - a2 / 24.0 * (1.0 - a2 / 30.0 * (1.0 - a2 / 56.0))
        S = (phi @ _LEVI).reshape(-1, 3, 3)
        return (_I3 - s2 * a2 * _I3) + s1 * S + s2 * (phi[:, :, None] * phi[:, None, :])
    return rotvec_to_dcm(phi)


_GK = (_B * _GP) / (_A * _GE) - 1.0
_GM_ = _WIE**2 * _A**2 * _B / _GM


def _step(lat, lon, h, v, C, f, w, dt):
    """One mechanisation step on raw arrays; returns (lat, lon, h, v, C, f_n)."""
    sL = np.sin(lat)
    cL = np.cos(lat)
    s2L = sL * sL
    w2 = 1.0 - _E2 * s2L
    sw = np.sqrt(w2)
    R_Nh = _A / sw + h
    R_Mh = _A * (1.0 - _E2) / (w2 * sw) + h
    vE, vN = v[:, 0], v[:, 1]
    # omega_in^n = omega_ie^n + omega_en^n, and 2 omega_ie + omega_en (Coriolis + transport)
    en_y = vE / R_Nh
    w_in = np.stack([-vN / R_Mh, _WIE * cL + en_y, (_WIE + en_y / cL) * sL], axis=-1)
    w_cor = w_in + np.stack([0.0 * cL, _WIE * cL, _WIE * sL], axis=-1)
    # attitude: C(k+1) = exp(-[w_in dt x]) C exp([w_ib dt x]); |w_in dt| < 1e-5 rad -> first order
    C_new = (C - ((w_in * dt) @ _LEVI).reshape(-1, 3, 3) @ C) @ _expm_so3(w * dt)
    f_n = ((C + C_new) @ f[:, :, None])[:, :, 0] * 0.5
    g = (
        _GE
        * (1.0 + _GK * s2L)
        / sw
        * (1.0 - 2.0 / _A * (1.0 + _F + _GM_ - 2.0 * _F * s2L) * h + 3.0 / _A**2 * h * h)
    )
    a = f_n - ((w_cor @ _LEVI).reshape(-1, 3, 3) @ v[:, :, None])[:, :, 0]
    a[:, 2] -= g
    v_new = v + a * dt
    v_mid = 0.5 * (v + v_new)
    return (
        lat + v_mid[:, 1] / R_Mh * dt,
        lon + v_mid[:, 0] / (R_Nh * cL) * dt,
        h + v_mid[:, 2] * dt,
        v_new,
        C_new,
        f_n,
    )


def _mechanise_run(nav, v, C, f_raw, w_raw, bias_a, bias_g, dts, reorth, sums):  # pragma: no cover
    """One run through its block of samples, equation by equation as :func:`_step` (compiled).

    Updates ``nav`` = (lat, lon, h) (3,), v (3,) and C (3, 3) in place; ``sums`` (3, 3) accumulates
    Σ f^n dt, Σ f^b dt and Σ ω^b dt (bias-corrected). f_raw, w_raw (N, 3) are the raw samples,
    bias_a, bias_g (3,) the running bias estimates, dts (N,) the holding times (≤ 0: skipped).
    """
    N = dts.shape[0]
    Cn = np.empty((3, 3))
    E = np.empty((3, 3))
    fn = np.empty(3)
    for k in range(N):
        dt = dts[k]
        if dt <= 0.0:
            continue
        f0 = f_raw[k, 0] - bias_a[0]
        f1 = f_raw[k, 1] - bias_a[1]
        f2 = f_raw[k, 2] - bias_a[2]
        g0 = w_raw[k, 0] - bias_g[0]
        g1 = w_raw[k, 1] - bias_g[1]
        g2 = w_raw[k, 2] - bias_g[2]
        sL = np.sin(nav[0])
        cL = np.cos(nav[0])
        s2L = sL * sL
        w2 = 1.0 - _E2 * s2L
        sw = np.sqrt(w2)
        R_Nh = _A / sw + nav[2]
        R_Mh = _A * (1.0 - _E2) / (w2 * sw) + nav[2]
        vE, vN, vU = v[0], v[1], v[2]
        # ω_in^n = ω_ie^n + ω_en^n, and 2 ω_ie^n + ω_en^n (Coriolis + transport)
        en_y = vE / R_Nh
        wi0, wi1, wi2 = -vN / R_Mh, _WIE * cL + en_y, (_WIE + en_y / cL) * sL
        wc0, wc1, wc2 = wi0, wi1 + _WIE * cL, wi2 + _WIE * sL
        # attitude: C⁺ = (I − [ω_in dt ×]) C exp([ω_ib dt ×])
        p0, p1, p2 = g0 * dt, g1 * dt, g2 * dt
        a2 = p0 * p0 + p1 * p1 + p2 * p2
        if a2 < 1e-2:  # Taylor series of sin(a)/a and (1 − cos a)/a² (error < 1e-16)
            s1 = 1.0 - a2 / 6.0 * (1.0 - a2 / 20.0 * (1.0 - a2 / 42.0))
            s2 = 0.5 - a2 / 24.0 * (1.0 - a2 / 30.0 * (1.0 - a2 / 56.0))
        else:
            ang = np.sqrt(a2)
            s1 = np.sin(ang) / ang
            s2 = (1.0 - np.cos(ang)) / a2
        # exp([p×]) = I + s1 [p×] + s2 [p×]², [p×]² = p pᵀ − a² I
        E[0, 0] = 1.0 + s2 * (p0 * p0 - a2)
        E[1, 1] = 1.0 + s2 * (p1 * p1 - a2)
        E[2, 2] = 1.0 + s2 * (p2 * p2 - a2)
        E[0, 1] = -s1 * p2 + s2 * p0 * p1
        E[1, 0] = s1 * p2 + s2 * p0 * p1
        E[0, 2] = s1 * p1 + s2 * p0 * p2
        E[2, 0] = -s1 * p1 + s2 * p0 * p2
        E[1, 2] = -s1 * p0 + s2 * p1 * p2
        E[2, 1] = s1 * p0 + s2 * p1 * p2
        q0, q1, q2 = wi0 * dt, wi1 * dt, wi2 * dt
        for j in range(3):  # (I − [q×]) C, column j
            c0, c1, c2 = C[0, j], C[1, j], C[2, j]
            Cn[0, j] = c0 + q2 * c1 - q1 * c2
            Cn[1, j] = c1 - q2 * c0 + q0 * c2
            Cn[2, j] = c2 + q1 * c0 - q0 * c1
        # f^n = ½ (C + C⁺) f^b, the mid-interval attitude
        for i in range(3):
            n0 = Cn[i, 0] * E[0, 0] + Cn[i, 1] * E[1, 0] + Cn[i, 2] * E[2, 0]
            n1 = Cn[i, 0] * E[0, 1] + Cn[i, 1] * E[1, 1] + Cn[i, 2] * E[2, 1]
            n2 = Cn[i, 0] * E[0, 2] + Cn[i, 1] * E[1, 2] + Cn[i, 2] * E[2, 2]
            fn[i] = ((C[i, 0] + n0) * f0 + (C[i, 1] + n1) * f1 + (C[i, 2] + n2) * f2) * 0.5
            C[i, 0], C[i, 1], C[i, 2] = n0, n1, n2
        # WGS-84 normal gravity at (L, h)
        g = (
            _GE
            * (1.0 + _GK * s2L)
            / sw
            * (1.0 - 2.0 / _A * (1.0 + _F + _GM_ - 2.0 * _F * s2L) * nav[2] + 3.0 / _A**2 * nav[2] * nav[2])
        )
        # v̇ = f^n − (2 ω_ie^n + ω_en^n) × v + g^n
        a0 = fn[0] - (wc1 * vU - wc2 * vN)
        a1 = fn[1] - (wc2 * vE - wc0 * vU)
        a2_ = fn[2] - (wc0 * vN - wc1 * vE) - g
        nE, nN, nU = vE + a0 * dt, vN + a1 * dt, vU + a2_ * dt
        # position by the trapezoid rule
        nav[0] += 0.5 * (vN + nN) / R_Mh * dt
        nav[1] += 0.5 * (vE + nE) / (R_Nh * cL) * dt
        nav[2] += 0.5 * (vU + nU) * dt
        v[0], v[1], v[2] = nE, nN, nU
        for i in range(3):
            sums[0, i] += fn[i] * dt
        sums[1, 0] += f0 * dt
        sums[1, 1] += f1 * dt
        sums[1, 2] += f2 * dt
        sums[2, 0] += g0 * dt
        sums[2, 1] += g1 * dt
        sums[2, 2] += g2 * dt
    if reorth:
        # nearest rotation = the polar factor of C (the numpy path: U Vᵀ of an SVD), by
        # Newton–Schulz, C ← C (3I − CᵀC)/2: quadratic convergence from a nearly orthonormal
        # C (a block of steps leaves ‖CᵀC − I‖ ≈ 1e-13), round-off in one or two iterations
        for _ in range(6):
            err = 0.0
            for i in range(3):
                for j in range(3):
                    g = C[0, i] * C[0, j] + C[1, i] * C[1, j] + C[2, i] * C[2, j]
                    E[i, j] = (3.0 if i == j else 0.0) - g  # E: work array, 3I − CᵀC
                    err = max(err, abs(g - (1.0 if i == j else 0.0)))
            if err < 4e-16:
                break
            for i in range(3):
                c0, c1, c2 = C[i, 0], C[i, 1], C[i, 2]
                for j in range(3):
                    C[i, j] = 0.5 * (c0 * E[0, j] + c1 * E[1, j] + c2 * E[2, j])


def _mechanise_runs(lat, lon, h, v, C, f_raw, w_raw, bias_a, bias_g, dts, reorth, sums):  # pragma: no cover
    """The compiled path of :func:`propagate_block`: every run through its block of samples.

    Updates lat, lon, h (B,), v (B, 3), C (B, 3, 3) in place; sums (B, 3, 3) accumulates Σ f^n dt,
    Σ f^b dt and Σ ω^b dt (bias-corrected). f_raw, w_raw (1 or B, N, 3) are the raw samples (one
    block shared by every run, or one per run), bias_a, bias_g (B, 3) the running bias estimates.
    """
    nav = np.empty(3)
    for r in range(lat.shape[0]):
        rs = r if f_raw.shape[0] > 1 else 0
        nav[0], nav[1], nav[2] = lat[r], lon[r], h[r]
        _mechanise_run(nav, v[r], C[r], f_raw[rs], w_raw[rs], bias_a[r], bias_g[r], dts, reorth, sums[r])
        lat[r], lon[r], h[r] = nav[0], nav[1], nav[2]


_MECHANISE_RUN = Kernel(_mechanise_run)
_MECHANISE = Kernel(_mechanise_runs, uses=(_MECHANISE_RUN,))


def mechanise_step(state: InsState, f_b_mps2, w_b_radps, dt_s: float, return_fn: bool = False):
    """Advance all B solutions by one IMU sample (rectangular rate integration).

    Attitude: ``C(k+1) = exp(-[w_in^n dt x]) C(k) exp([w_ib^b dt x])`` (Earth rate and
    transport rate included); velocity: ``v_dot = C_b^n f^b - (2 w_ie^n + w_en^n) x v + g^n``
    with WGS-84 normal gravity, ``f^n`` from the mid-interval attitude; position by the
    trapezoid rule in lat/lon/h.

    Parameters
    ----------
    state : InsState
    f_b_mps2, w_b_radps : array_like (3,) or (B, 3)
        Raw IMU sample (biases in ``state`` are subtracted here) [m/s^2], [rad/s].
    dt_s : float
        Sample interval [s] (> 0).
    return_fn : bool
        Also return ``f^n`` [m/s^2], shape (B, 3).

    Returns
    -------
    InsState, or (InsState, numpy.ndarray) if ``return_fn``.
    """
    B = state.B
    f = np.broadcast_to(np.asarray(f_b_mps2, dtype=float) - state.bias_a_mps2, (B, 3))
    w = np.broadcast_to(np.asarray(w_b_radps, dtype=float) - state.bias_g_radps, (B, 3))
    lat, lon, h, v, C, f_n = _step(
        state.lat_rad, state.lon_rad, state.h_m, state.v_enu_mps, state.C_bn, f, w, dt_s
    )
    new = replace(state, lat_rad=lat, lon_rad=lon, h_m=h, v_enu_mps=v, C_bn=C, t_s=state.t_s + dt_s)
    return (new, f_n) if return_fn else new


def _holding_times(t: np.ndarray, t0_s: float, t_stop: float) -> np.ndarray:
    """How long each sample is held: from max(its time, ``t0_s``) to the next sample or ``t_stop``."""
    starts = np.concatenate([[t0_s], np.maximum(t[1:], t0_s)])
    ends = np.minimum(np.concatenate([t[1:], [t_stop]]), t_stop)
    return ends - starts


def _propagate_compiled(
    kernel, state: InsState, f_all, w_all, dts: np.ndarray, reorthonormalise: bool, Ts: float
):
    """The compiled path, one run at a time (navlab.jit): (lat, lon, h, v, C, Σf^n, f̄^b, ω̄^b)."""
    B = state.B
    lat, lon, h = (np.array(a, dtype=float, order="C") for a in (state.lat_rad, state.lon_rad, state.h_m))
    v, C = np.array(state.v_enu_mps, dtype=float, order="C"), np.array(state.C_bn, dtype=float, order="C")
    sums = np.zeros((B, 3, 3))  # Σ f^n dt, Σ f^b dt, Σ ω^b dt
    c = carray
    kernel(
        lat,
        lon,
        h,
        v,
        C,
        c(f_all),
        c(w_all),
        c(state.bias_a_mps2),
        c(state.bias_g_radps),
        c(dts),
        reorthonormalise,
        sums,
    )
    return lat, lon, h, v, C, sums[:, 0] / Ts, sums[:, 1] / Ts, sums[:, 2] / Ts


def _propagate_numpy(state: InsState, f_all, w_all, dts: np.ndarray, reorthonormalise: bool, Ts: float):
    """The numpy path, batched over the runs (the reference): as :func:`_propagate_compiled`."""
    B, N = state.B, dts.shape[0]
    f_all = np.broadcast_to(f_all - state.bias_a_mps2[:, None, :], (B, N, 3))
    w_all = np.broadcast_to(w_all - state.bias_g_radps[:, None, :], (B, N, 3))
    lat, lon, h, v, C = state.lat_rad, state.lon_rad, state.h_m, state.v_enu_mps, state.C_bn
    f_sum_n = np.zeros((B, 3))
    for k in np.flatnonzero(dts > 0.0):
        dt = float(dts[k])
        lat, lon, h, v, C, f_n = _step(lat, lon, h, v, C, f_all[:, k], w_all[:, k], dt)
        f_sum_n += f_n * dt
    if reorthonormalise:
        C = orthonormalize(C)
    pos = np.clip(dts, 0.0, None)
    f_mean_b = np.einsum("k,bki->bi", pos, f_all) / Ts
    w_mean_b = np.einsum("k,bki->bi", pos, w_all) / Ts
    return lat, lon, h, v, C, f_sum_n / Ts, f_mean_b, w_mean_b


def propagate_block(
    state: InsState, t_imu_s, f_b_mps2, w_b_radps, t_end_s: float | None = None, reorthonormalise: bool = True
):
    """Propagate B solutions through a block of IMU samples, e.g. between two GNSS epochs.

    The sample at ``t_imu_s[k]`` is held over ``[t_imu_s[k], t_imu_s[k+1])``; sample 0 is
    used from ``state.t_s`` on, and the last sample is held until ``t_end_s`` (default: its
    own time stamp, so it only closes the block). Pass the samples with
    ``state.t_s <= t_imu_s[k] < t_end_s`` (``numpy.searchsorted``) and the solutions land
    exactly on the aiding epochs.

    Parameters
    ----------
    state : InsState
    t_imu_s : array_like (N,)
        Sample times [s], increasing.
    f_b_mps2, w_b_radps : array_like (N, 3) or (B, N, 3)
        Raw samples [m/s^2], [rad/s]; a (N, 3) block is shared by the whole batch.
    t_end_s : float, optional
        End time of the block [s].
    reorthonormalise : bool
        Project ``C_b^n`` back onto SO(3) at the end of the block.

    Returns
    -------
    InsState
        The solutions at ``t_end_s`` (or the last sample time).
    ImuBlock
        Mean bias-corrected body specific force and rate, and mean ENU specific force.
    """
    t = np.asarray(t_imu_s, dtype=float)
    f_all = np.asarray(f_b_mps2, dtype=float)
    w_all = np.asarray(w_b_radps, dtype=float)
    if f_all.ndim == 2:
        f_all = f_all[None]
        w_all = w_all[None]
    t_stop = float(t[-1]) if t_end_s is None else float(t_end_s)
    dts = _holding_times(t, state.t_s, t_stop)
    T = float(dts[dts > 0.0].sum())
    Ts = T if T > 0 else 1.0
    kernel = _MECHANISE.get()
    if kernel is not None:
        lat, lon, h, v, C, f_sum_n, f_mean_b, w_mean_b = _propagate_compiled(
            kernel, state, f_all, w_all, dts, reorthonormalise, Ts
        )
    else:
        lat, lon, h, v, C, f_sum_n, f_mean_b, w_mean_b = _propagate_numpy(
            state, f_all, w_all, dts, reorthonormalise, Ts
        )
    new = replace(state, lat_rad=lat, lon_rad=lon, h_m=h, v_enu_mps=v, C_bn=C, t_s=t_stop)
    return new, ImuBlock(T, t.shape[0], f_mean_b, w_mean_b, f_sum_n)


def apply_correction(state: InsState, dx, bias_feedback: bool = True) -> InsState:
    """Closed-loop correction: remove an estimated error state from the B solutions.

    Parameters
    ----------
    state : InsState
    dx : array_like (B, 15) or (B, >=9)
        Estimated error (INS - truth) in the order ``[phi(ENU, rad), dv(ENU, m/s),
        dp(N, E, U m), eps(body rad/s), nabla(body m/s^2)]``.
    bias_feedback : bool
        Add ``eps`` / ``nabla`` to the running bias estimates (they are then subtracted
        from the raw IMU samples). The caller must zero the corrected states afterwards.

    Returns
    -------
    InsState
        ``C <- exp([phi x]) C``, ``v <- v - dv``, ``lat <- lat - dp_N/R_Mh``,
        ``lon <- lon - dp_E/(R_Nh cos L)``, ``h <- h - dp_U``, ``bias += [eps, nabla]``.
    """
    dx = np.asarray(dx, dtype=float)
    if dx.ndim != 2 or dx.shape[0] != state.B or dx.shape[1] < 9:
        raise NavlabError(
            f"correction has shape {dx.shape}; pass (B={state.B}, 15) ordered [phi, dv, dp, eps, nabla]."
        )
    R_Mh, R_Nh = radii(state.lat_rad, state.h_m)
    C = orthonormalize(rotvec_to_dcm(dx[:, 0:3]) @ state.C_bn)
    lat = state.lat_rad - dx[:, 6] / R_Mh
    lon = state.lon_rad - dx[:, 7] / (R_Nh * np.cos(state.lat_rad))
    bg, ba = state.bias_g_radps, state.bias_a_mps2
    if bias_feedback and dx.shape[1] >= 15:
        bg = bg + dx[:, 9:12]
        ba = ba + dx[:, 12:15]
    return replace(
        state,
        C_bn=C,
        v_enu_mps=state.v_enu_mps - dx[:, 3:6],
        lat_rad=lat,
        lon_rad=lon,
        h_m=state.h_m - dx[:, 8],
        bias_g_radps=bg,
        bias_a_mps2=ba,
    )


def _error_model_inputs(lat_rad, h_m, v_enu_mps, f_n_mps2, C_bn):
    """The inputs of :func:`error_model_FG` as float arrays broadcast to one batch size B."""
    lat = np.atleast_1d(np.asarray(lat_rad, dtype=float))
    h = np.broadcast_to(np.asarray(h_m, dtype=float), lat.shape)
    v = np.asarray(v_enu_mps, dtype=float).reshape(-1, 3)
    fn = np.asarray(f_n_mps2, dtype=float).reshape(-1, 3)
    C = np.asarray(C_bn, dtype=float).reshape(-1, 3, 3)
    B = max(lat.shape[0], v.shape[0], fn.shape[0], C.shape[0])
    lat, h = np.broadcast_to(lat, (B,)), np.broadcast_to(h, (B,))
    v, fn, C = np.broadcast_to(v, (B, 3)), np.broadcast_to(fn, (B, 3)), np.broadcast_to(C, (B, 3, 3))
    return lat, h, v, fn, C


def _attitude_velocity_blocks(lat, h, v, fn):
    """The §8.0 blocks of the attitude and velocity errors, against position in radians:
    (Maa, Mav, Map, Mva, Mvv, Mvp), each (B, 3, 3).
    """
    B = lat.shape[0]
    sL, cL, tL = np.sin(lat), np.cos(lat), np.tan(lat)
    R_Mh, R_Nh = radii(lat, h)
    wie = 7.2921151467e-5
    vE, vN = v[:, 0], v[:, 1]
    w_ie = earth_rate_enu(lat)
    w_en = transport_rate_enu(lat, h, v)
    w_in = w_ie + w_en
    N1 = np.zeros((B, 3, 3))
    N1[:, 1, 0] = -wie * sL
    N1[:, 2, 0] = wie * cL
    N2 = np.zeros((B, 3, 3))
    N2[:, 0, 2] = vN / R_Mh**2
    N2[:, 1, 2] = -vE / R_Nh**2
    N2[:, 2, 0] = vE / (cL**2 * R_Nh)
    N2[:, 2, 2] = -vE * tL / R_Nh**2
    Mav = np.zeros((B, 3, 3))
    Mav[:, 0, 1] = -1.0 / R_Mh
    Mav[:, 1, 0] = 1.0 / R_Nh
    Mav[:, 2, 0] = tL / R_Nh
    Maa = -skew(w_in)
    Map = N1 + N2
    Mva = skew(fn)
    Mvv = skew(v) @ Mav - skew(2.0 * w_ie + w_en)
    Mvp = skew(v) @ (2.0 * N1 + N2)
    return Maa, Mav, Map, Mva, Mvv, Mvp


def _position_blocks(lat, h, v):
    """The §8.0 blocks of the position errors and the radians-to-metres scaling:
    (Mpv, Mpp, D, D⁻¹), each (B, 3, 3).
    """
    B = lat.shape[0]
    cL, tL = np.cos(lat), np.tan(lat)
    R_Mh, R_Nh = radii(lat, h)
    vE, vN = v[:, 0], v[:, 1]
    Mpv = np.zeros((B, 3, 3))
    Mpv[:, 0, 1] = 1.0 / R_Mh
    Mpv[:, 1, 0] = 1.0 / (cL * R_Nh)
    Mpv[:, 2, 2] = 1.0
    Mpp = np.zeros((B, 3, 3))
    Mpp[:, 0, 2] = -vN / R_Mh**2
    Mpp[:, 1, 0] = vE * tL / (cL * R_Nh)
    Mpp[:, 1, 2] = -vE / (cL * R_Nh**2)
    D = np.zeros((B, 3, 3))
    D[:, 0, 0], D[:, 1, 1], D[:, 2, 2] = R_Mh, R_Nh * cL, 1.0
    Dinv = np.zeros((B, 3, 3))
    Dinv[:, 0, 0], Dinv[:, 1, 1], Dinv[:, 2, 2] = 1.0 / R_Mh, 1.0 / (R_Nh * cL), 1.0
    return Mpv, Mpp, D, Dinv


def _noise_input(C) -> np.ndarray:
    """G (B, 15, 12): gyro and accelerometer white noise through C, the bias driving noises."""
    G = np.zeros((C.shape[0], 15, 12))
    G[:, 0:3, 0:3] = -C
    G[:, 3:6, 3:6] = C
    G[:, 9:12, 6:9] = np.eye(3)
    G[:, 12:15, 9:12] = np.eye(3)
    return G


def error_model_FG(
    lat_rad, h_m, v_enu_mps, f_n_mps2, C_bn, gravity_gradient: bool = False, tau_g_s=None, tau_a_s=None
):
    """Continuous-time 15-state error model ``x_dot = F x + G w`` of ALGORITHMS.md §8.0.

    Position-error states are METRES (N, E, U). Noise vector
    ``w = [gyro white (3, body rad/s), accel white (3, body m/s^2), gyro-bias driving (3),
    accel-bias driving (3)]``.

    Parameters
    ----------
    lat_rad, h_m : array_like (B,)
        Current latitude [rad] and height [m].
    v_enu_mps, f_n_mps2 : array_like (B, 3)
        Velocity [m/s] and specific force in ENU [m/s^2] (e.g. ``ImuBlock.f_n_mean_mps2``).
    C_bn : array_like (B, 3, 3)
        Attitude.
    gravity_gradient : bool
        Add ``dv_U_dot += 2 g / R dp_U`` (omitted by default as in the spec).
    tau_g_s, tau_a_s : float, optional
        If given, first-order Gauss-Markov biases (``-1/tau`` on the diagonal) instead of
        random walks.

    Returns
    -------
    F : numpy.ndarray (B, 15, 15)
    G : numpy.ndarray (B, 15, 12)
    """
    lat, h, v, fn, C = _error_model_inputs(lat_rad, h_m, v_enu_mps, f_n_mps2, C_bn)
    B = lat.shape[0]
    Maa, Mav, Map, Mva, Mvv, Mvp = _attitude_velocity_blocks(lat, h, v, fn)
    Mpv, Mpp, D, Dinv = _position_blocks(lat, h, v)
    F = np.zeros((B, 15, 15))
    F[:, 0:3, 0:3] = Maa
    F[:, 0:3, 3:6] = Mav
    F[:, 0:3, 6:9] = Map @ Dinv
    F[:, 0:3, 9:12] = -C
    F[:, 3:6, 0:3] = Mva
    F[:, 3:6, 3:6] = Mvv
    F[:, 3:6, 6:9] = Mvp @ Dinv
    F[:, 3:6, 12:15] = C
    F[:, 6:9, 3:6] = D @ Mpv
    F[:, 6:9, 6:9] = D @ Mpp @ Dinv
    if gravity_gradient:
        R_Mh, R_Nh = radii(lat, h)
        F[:, 5, 8] += 2.0 * normal_gravity(lat, h) / np.sqrt(R_Mh * R_Nh)
    if tau_g_s is not None:
        F[:, 9:12, 9:12] = -np.eye(3) / float(tau_g_s)
    if tau_a_s is not None:
        F[:, 12:15, 12:15] = -np.eye(3) / float(tau_a_s)
    return F, _noise_input(C)


def discretise(F, G, Qc, T_s):
    """Second-order discretisation of ALGORITHMS.md §8.0.

    ``Phi = I + F T + (F T)^2 / 2``; ``Q_d = (Phi G Qc G^T Phi^T + G Qc G^T) T / 2``.

    Parameters
    ----------
    F : (B, n, n); G : (B, n, q); Qc : (q, q) or (B, q, q) continuous PSDs.
    T_s : float or (B,)
        Step [s] (one per matrix of the stack for an array).

    Returns
    -------
    Phi, Qd : numpy.ndarray (B, n, n)
    """
    F = np.asarray(F, dtype=float)
    n = F.shape[-1]
    T_s = np.asarray(T_s, dtype=float)[..., None, None]
    FT = F * T_s
    Phi = np.eye(n) + FT + FT @ FT / 2.0
    GQG = G @ np.asarray(Qc, dtype=float) @ np.swapaxes(G, -1, -2)
    Qd = 0.5 * (Phi @ GQG @ np.swapaxes(Phi, -1, -2) + GQG) * T_s
    return Phi, 0.5 * (Qd + np.swapaxes(Qd, -1, -2))
