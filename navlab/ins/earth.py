"""WGS-84 Earth model, frames and small rotation helpers (numpy, batched).

Conventions (ALGORITHMS.md section 8.0):

* navigation frame ``n`` = local-level ENU (x east, y north, z up);
* vehicle/body frame for attitude angles = RFU (x right, y forward, z up);
* heading ``psi`` is measured clockwise from north, so that for level attitude
  ``C_b^n = [[cos psi, sin psi, 0], [-sin psi, cos psi, 0], [0, 0, 1]]``;
* latitude / longitude are in RADIANS in every function of this module unless
  the argument name ends in ``_deg``; heights and ECEF coordinates in metres.

Every function accepts a leading batch shape: scalars, ``(B,)`` or ``(B, 3)`` arrays
broadcast the usual numpy way; matrices come back with shape ``(..., 3, 3)``.

The ellipsoid is WGS-84 (a = 6378137 m, f = 1/298.257223563). ALGORITHMS.md quotes the
PSINS value f = 1/298.257; the difference changes R_M, R_N by < 1e-9 relative and
positions converted through ECEF by < 1 mm, which is why the exact WGS-84 value is used
here (smartLoc ECEF coordinates are WGS-84).

The rotation-vector conversions are called a few times per epoch per filter on a handful of runs
(≈ 25 µs of numpy overhead each); they run compiled (navlab.jit, one loop per matrix) when numba
is available, with the numpy path as the reference the tests compare with.
"""

from __future__ import annotations

import numpy as np

from navlab.jit import Kernel, carray

#: WGS-84 semi-major axis [m].
WGS84_A_M = 6378137.0
#: WGS-84 flattening [-].
WGS84_F = 1.0 / 298.257223563
#: First eccentricity squared [-].
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
#: Semi-minor axis [m].
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)
#: Earth rotation rate [rad/s].
OMEGA_IE_RADPS = 7.2921151467e-5
#: Earth gravitational constant GM [m^3/s^2].
WGS84_GM_M3PS2 = 3.986004418e14
#: Normal gravity at the equator [m/s^2] (Somigliana).
GAMMA_E_MPS2 = 9.7803253359
#: Normal gravity at the pole [m/s^2] (Somigliana).
GAMMA_P_MPS2 = 9.8321849378
#: Standard gravity used to convert accelerometer readings given in g [m/s^2].
G0_MPS2 = 9.80665


def radii(lat_rad, h_m=0.0):
    """Meridian and prime-vertical radii of curvature.

    Parameters
    ----------
    lat_rad : array_like
        Geodetic latitude [rad], any shape.
    h_m : array_like, optional
        Ellipsoidal height [m]; if given, ``R_M + h`` and ``R_N + h`` are returned.

    Returns
    -------
    R_Mh_m, R_Nh_m : numpy.ndarray
        ``R_M + h`` (north-south) and ``R_N + h`` (east-west) [m].
    """
    s = np.sin(lat_rad)
    w2 = 1.0 - WGS84_E2 * s * s
    R_N = WGS84_A_M / np.sqrt(w2)
    R_M = WGS84_A_M * (1.0 - WGS84_E2) / (w2 * np.sqrt(w2))
    return R_M + h_m, R_N + h_m


def normal_gravity(lat_rad, h_m=0.0):
    """Magnitude of WGS-84 normal gravity (Somigliana + second-order free-air term).

    Parameters
    ----------
    lat_rad : array_like
        Geodetic latitude [rad].
    h_m : array_like, optional
        Ellipsoidal height [m].

    Returns
    -------
    numpy.ndarray
        Gravity magnitude [m/s^2]; the gravity vector in ENU is ``[0, 0, -g]``.
    """
    s2 = np.sin(lat_rad) ** 2
    k = (WGS84_B_M * GAMMA_P_MPS2) / (WGS84_A_M * GAMMA_E_MPS2) - 1.0
    g0 = GAMMA_E_MPS2 * (1.0 + k * s2) / np.sqrt(1.0 - WGS84_E2 * s2)
    m = OMEGA_IE_RADPS**2 * WGS84_A_M**2 * WGS84_B_M / WGS84_GM_M3PS2
    h = np.asarray(h_m, dtype=float)
    return g0 * (
        1.0 - 2.0 / WGS84_A_M * (1.0 + WGS84_F + m - 2.0 * WGS84_F * s2) * h + 3.0 / WGS84_A_M**2 * h * h
    )


def earth_rate_enu(lat_rad):
    """Earth rotation rate expressed in ENU, ``omega_ie^n = [0, w cos L, w sin L]`` [rad/s].

    Parameters
    ----------
    lat_rad : array_like
        Latitude [rad], shape ``(...)``.

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3)`` [rad/s].
    """
    lat = np.asarray(lat_rad, dtype=float)
    return np.stack([np.zeros_like(lat), OMEGA_IE_RADPS * np.cos(lat), OMEGA_IE_RADPS * np.sin(lat)], axis=-1)


def transport_rate_enu(lat_rad, h_m, v_enu_mps):
    """Transport rate ``omega_en^n = [-v_N/R_Mh, v_E/R_Nh, v_E tan L / R_Nh]`` [rad/s].

    Parameters
    ----------
    lat_rad, h_m : array_like
        Latitude [rad] and height [m], shape ``(...)``.
    v_enu_mps : array_like
        Velocity east, north, up [m/s], shape ``(..., 3)``.

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3)`` [rad/s].
    """
    v = np.asarray(v_enu_mps, dtype=float)
    R_Mh, R_Nh = radii(lat_rad, h_m)
    return np.stack([-v[..., 1] / R_Mh, v[..., 0] / R_Nh, v[..., 0] * np.tan(lat_rad) / R_Nh], axis=-1)


def geodetic_to_ecef(lat_rad, lon_rad, h_m):
    """Geodetic (lat, lon [rad], h [m]) to ECEF xyz [m].

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3)`` [m].
    """
    s, c = np.sin(lat_rad), np.cos(lat_rad)
    R_N = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * s * s)
    return np.stack(
        [
            (R_N + h_m) * c * np.cos(lon_rad),
            (R_N + h_m) * c * np.sin(lon_rad),
            (R_N * (1.0 - WGS84_E2) + h_m) * s,
        ],
        axis=-1,
    )


def ecef_to_geodetic(xyz_m):
    """ECEF xyz [m] to geodetic latitude, longitude [rad] and height [m].

    Uses Bowring's initial value and three Newton-type refinements (sub-millimetre for
    points from the Earth's centre region excluded up to GNSS orbit altitudes).

    Parameters
    ----------
    xyz_m : array_like
        Shape ``(..., 3)`` [m].

    Returns
    -------
    lat_rad, lon_rad, h_m : numpy.ndarray
        Each of shape ``(...)``.
    """
    xyz = np.asarray(xyz_m, dtype=float)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    ep2 = WGS84_E2 / (1.0 - WGS84_E2)
    theta = np.arctan2(z * WGS84_A_M, p * WGS84_B_M)
    lat = np.arctan2(z + ep2 * WGS84_B_M * np.sin(theta) ** 3, p - WGS84_E2 * WGS84_A_M * np.cos(theta) ** 3)
    for _ in range(3):
        s = np.sin(lat)
        R_N = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * s * s)
        h = np.where(
            np.abs(np.cos(lat)) > 1e-10,
            p / np.maximum(np.cos(lat), 1e-300) - R_N,
            np.abs(z) - WGS84_B_M,
        )
        lat = np.arctan2(z, p * (1.0 - WGS84_E2 * R_N / (R_N + h)))
    s = np.sin(lat)
    R_N = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * s * s)
    c = np.cos(lat)
    h = np.where(np.abs(c) > 1e-10, p / np.where(np.abs(c) > 1e-10, c, 1.0) - R_N, np.abs(z) - WGS84_B_M)
    return lat, lon, h


def rot_ecef_to_enu(lat_rad, lon_rad):
    """Rotation matrix ``C_e^n`` (ECEF to ENU) at the given origin.

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3, 3)``; ``enu = C_e^n @ (xyz - xyz0)``.
    """
    sL, cL = np.sin(lat_rad), np.cos(lat_rad)
    sl, cl = np.sin(lon_rad), np.cos(lon_rad)
    z = np.zeros_like(sL * sl)
    return np.stack(
        [
            np.stack([-sl + z, cl + z, z], axis=-1),
            np.stack([-sL * cl, -sL * sl, cL + z], axis=-1),
            np.stack([cL * cl, cL * sl, sL + z], axis=-1),
        ],
        axis=-2,
    )


def ecef_to_enu(xyz_m, lat0_rad, lon0_rad, h0_m):
    """ECEF points [m] to local ENU [m] about the origin (lat0, lon0 [rad], h0 [m]).

    Parameters
    ----------
    xyz_m : array_like
        Shape ``(..., 3)``.

    Returns
    -------
    numpy.ndarray
        ENU coordinates, shape ``(..., 3)`` [m].
    """
    xyz0 = geodetic_to_ecef(lat0_rad, lon0_rad, h0_m)
    C = rot_ecef_to_enu(lat0_rad, lon0_rad)
    return np.einsum("...ij,...j->...i", C, np.asarray(xyz_m, dtype=float) - xyz0)


def enu_to_ecef(enu_m, lat0_rad, lon0_rad, h0_m):
    """Local ENU [m] about (lat0, lon0 [rad], h0 [m]) back to ECEF [m]; inverse of `ecef_to_enu`."""
    xyz0 = geodetic_to_ecef(lat0_rad, lon0_rad, h0_m)
    C = rot_ecef_to_enu(lat0_rad, lon0_rad)
    return xyz0 + np.einsum("...ji,...j->...i", C, np.asarray(enu_m, dtype=float))


def geodetic_to_enu(lat_rad, lon_rad, h_m, lat0_rad, lon0_rad, h0_m):
    """Geodetic coordinates to local ENU [m] about an origin (exact, through ECEF)."""
    return ecef_to_enu(geodetic_to_ecef(lat_rad, lon_rad, h_m), lat0_rad, lon0_rad, h0_m)


def enu_to_geodetic(enu_m, lat0_rad, lon0_rad, h0_m):
    """Local ENU [m] to geodetic (lat [rad], lon [rad], h [m]) (exact, through ECEF)."""
    return ecef_to_geodetic(enu_to_ecef(enu_m, lat0_rad, lon0_rad, h0_m))


def skew(v):
    """Cross-product matrix ``[v x]`` so that ``skew(a) @ b == cross(a, b)``.

    Parameters
    ----------
    v : array_like
        Shape ``(..., 3)``.

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3, 3)``.
    """
    v = np.asarray(v, dtype=float)
    S = np.zeros((*v.shape[:-1], 3, 3))
    S[..., 0, 1] = -v[..., 2]
    S[..., 0, 2] = v[..., 1]
    S[..., 1, 0] = v[..., 2]
    S[..., 1, 2] = -v[..., 0]
    S[..., 2, 0] = -v[..., 1]
    S[..., 2, 1] = v[..., 0]
    return S


def _rotvec_to_dcm_numpy(phi: np.ndarray) -> np.ndarray:
    a2 = np.sum(phi * phi, axis=-1)[..., None, None]
    a = np.sqrt(a2)
    small = a2 < 1e-16
    a_safe = np.where(small, 1.0, a)
    s1 = np.where(small, 1.0 - a2 / 6.0, np.sin(a_safe) / a_safe)
    s2 = np.where(small, 0.5 - a2 / 24.0, (1.0 - np.cos(a_safe)) / (a_safe * a_safe))
    S = skew(phi)
    return np.eye(3) + s1 * S + s2 * (S @ S)


def _rotvec_to_dcm_runs(phi, E):  # pragma: no cover - compiled by numba
    """E[i] = exp([φ_i ×]) = I + sin(a)/a [φ×] + (1 − cos a)/a² [φ×]², a = |φ_i| (Rodrigues)."""
    for i in range(phi.shape[0]):
        x, y, z = phi[i, 0], phi[i, 1], phi[i, 2]
        a2 = x * x + y * y + z * z
        if a2 < 1e-16:
            s1 = 1.0 - a2 / 6.0
            s2 = 0.5 - a2 / 24.0
        else:
            a = np.sqrt(a2)
            s1 = np.sin(a) / a
            s2 = (1.0 - np.cos(a)) / (a * a)
        # [φ×]² = φ φᵀ − a² I
        E[i, 0, 0] = 1.0 + s2 * (-(y * y) - z * z)
        E[i, 1, 1] = 1.0 + s2 * (-(x * x) - z * z)
        E[i, 2, 2] = 1.0 + s2 * (-(x * x) - y * y)
        E[i, 0, 1] = -s1 * z + s2 * x * y
        E[i, 1, 0] = s1 * z + s2 * x * y
        E[i, 0, 2] = s1 * y + s2 * x * z
        E[i, 2, 0] = -s1 * y + s2 * x * z
        E[i, 1, 2] = -s1 * x + s2 * y * z
        E[i, 2, 1] = s1 * x + s2 * y * z


_ROTVEC_TO_DCM = Kernel(_rotvec_to_dcm_runs)


def rotvec_to_dcm(phi_rad):
    """Rotation vector to rotation matrix, ``exp([phi x])`` (Rodrigues, batched).

    Parameters
    ----------
    phi_rad : array_like
        Rotation vector(s) [rad], shape ``(..., 3)``.

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3, 3)``. Accurate for small angles (series used below 1e-8 rad).
        Compiled (navlab.jit) when numba is available; the numpy path is the reference.
    """
    phi = np.asarray(phi_rad, dtype=float)
    kernel = _ROTVEC_TO_DCM.get()
    if kernel is None:
        return _rotvec_to_dcm_numpy(phi)
    E = np.empty((*phi.shape[:-1], 3, 3))
    kernel(carray(phi).reshape(-1, 3), E.reshape(-1, 3, 3))
    return E


def _dcm_to_rotvec_numpy(C: np.ndarray) -> np.ndarray:
    tr = np.trace(C, axis1=-2, axis2=-1)
    ang = np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))
    w = 0.5 * np.stack(
        [C[..., 2, 1] - C[..., 1, 2], C[..., 0, 2] - C[..., 2, 0], C[..., 1, 0] - C[..., 0, 1]], axis=-1
    )
    sa = np.sin(ang)[..., None]
    scale = np.where(sa > 1e-12, ang[..., None] / np.where(sa > 1e-12, sa, 1.0), 1.0)
    return w * scale


def _dcm_to_rotvec_runs(C, phi):  # pragma: no cover - compiled by numba
    """phi[i] = θ/sin θ · ½ (C − Cᵀ)^∨, cos θ = (tr C − 1)/2 (C[i] a rotation, θ < π)."""
    for i in range(C.shape[0]):
        c = (C[i, 0, 0] + C[i, 1, 1] + C[i, 2, 2] - 1.0) / 2.0
        ang = np.arccos(min(max(c, -1.0), 1.0))
        sa = np.sin(ang)
        scale = ang / sa if sa > 1e-12 else 1.0
        phi[i, 0] = 0.5 * (C[i, 2, 1] - C[i, 1, 2]) * scale
        phi[i, 1] = 0.5 * (C[i, 0, 2] - C[i, 2, 0]) * scale
        phi[i, 2] = 0.5 * (C[i, 1, 0] - C[i, 0, 1]) * scale


_DCM_TO_ROTVEC = Kernel(_dcm_to_rotvec_runs)


def dcm_to_rotvec(C):
    """Rotation matrix to rotation vector [rad] (inverse of `rotvec_to_dcm`, angles < pi).

    Compiled (navlab.jit) when numba is available; the numpy path is the reference.
    """
    C = np.asarray(C, dtype=float)
    kernel = _DCM_TO_ROTVEC.get()
    if kernel is None:
        return _dcm_to_rotvec_numpy(C)
    phi = np.empty(C.shape[:-1])
    kernel(carray(C).reshape(-1, 3, 3), phi.reshape(-1, 3))
    return phi


def orthonormalize(C):
    """Nearest rotation matrix (SVD polar projection), batched ``(..., 3, 3)``."""
    U, _, Vt = np.linalg.svd(C)
    return U @ Vt


def euler_to_dcm(pitch_rad, roll_rad, heading_rad):
    """Attitude angles to ``C_b^n`` (body RFU to ENU), ALGORITHMS.md section 8.0 convention.

    ``C_b^n = Rz(-heading) Rx(pitch) Ry(roll)``: pitch positive nose (body y) up, roll
    positive right side (body x) down, heading clockwise from north.

    Parameters
    ----------
    pitch_rad, roll_rad, heading_rad : array_like
        Angles [rad], broadcastable shapes ``(...)``.

    Returns
    -------
    numpy.ndarray
        Shape ``(..., 3, 3)``.
    """
    p, r, y = np.broadcast_arrays(
        np.asarray(pitch_rad, float), np.asarray(roll_rad, float), np.asarray(heading_rad, float)
    )
    cp, sp, cr, sr = np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    cy, sy = np.cos(y), np.sin(y)
    o, z = np.ones_like(p), np.zeros_like(p)
    Rz = np.stack([np.stack([cy, sy, z], -1), np.stack([-sy, cy, z], -1), np.stack([z, z, o], -1)], -2)
    Rx = np.stack([np.stack([o, z, z], -1), np.stack([z, cp, -sp], -1), np.stack([z, sp, cp], -1)], -2)
    Ry = np.stack([np.stack([cr, z, sr], -1), np.stack([z, o, z], -1), np.stack([-sr, z, cr], -1)], -2)
    return Rz @ Rx @ Ry


def dcm_to_euler(C_bn):
    """``C_b^n`` to (pitch, roll, heading) [rad]; inverse of `euler_to_dcm`.

    Returns
    -------
    pitch_rad, roll_rad, heading_rad : numpy.ndarray
        Heading wrapped to [0, 2 pi).
    """
    C = np.asarray(C_bn, dtype=float)
    pitch = np.arcsin(np.clip(C[..., 2, 1], -1.0, 1.0))
    roll = np.arctan2(-C[..., 2, 0], C[..., 2, 2])
    heading = np.mod(np.arctan2(C[..., 0, 1], C[..., 1, 1]), 2.0 * np.pi)
    return pitch, roll, heading


def wrap_pi(a_rad):
    """Wrap angles to [-pi, pi) [rad]."""
    return np.mod(np.asarray(a_rad) + np.pi, 2.0 * np.pi) - np.pi
