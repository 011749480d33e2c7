"""Coarse static alignment, gyro-bias initialisation and IMU mounting (body -> vehicle).

Frames: IMU body ``b`` (the sensor's own axes), vehicle ``v`` = RFU (x right, y forward,
z up, ALGORITHMS.md §8.0), navigation ``n`` = ENU. Heading is clockwise from north.

A MEMS gyro cannot gyrocompass (its bias, ~0.1 deg/s, is ~25x the Earth rate), so the
heading comes from outside: the RTK course once the car moves (`course_heading`), or a
value the user gives. Roll and pitch come from the mean static specific force.

rtkx_drive_0708 mounting (data README): IMU x points backward, z up, y therefore right,
plus about -6.8 deg pitch and +5.4 deg yaw misalignment. `body_to_vehicle` builds
``C_b^v`` from those numbers; `vehicle_tilt_from_static` tells how level the VEHICLE
looks through a candidate ``C_b^v`` (a parked car should give roll, pitch within a few
degrees of zero), which is the check the README asks for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from navlab.errors import NavlabError
from navlab.ins.earth import dcm_to_euler, earth_rate_enu, euler_to_dcm, normal_gravity

__all__ = [
    "RTKX_NOMINAL_C_BV",
    "AlignmentResult",
    "align_moving",
    "align_static",
    "body_to_vehicle",
    "course_heading",
    "motion_start_time",
    "triad_attitude",
    "vehicle_tilt_from_static",
]

#: Nominal rtkx IMU axes in the vehicle RFU frame (columns: IMU x = backward,
#: IMU y = right, IMU z = up), i.e. ``f^v = RTKX_NOMINAL_C_BV @ f^b``.
RTKX_NOMINAL_C_BV = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def body_to_vehicle(
    pitch_mis_deg: float = -6.8,
    yaw_mis_deg: float = 5.4,
    roll_mis_deg: float = 0.0,
    nominal=RTKX_NOMINAL_C_BV,
):
    """IMU-body to vehicle (RFU) rotation ``C_b^v``.

    ``C_b^v = euler_to_dcm(pitch_mis, roll_mis, yaw_mis) @ nominal``: the misalignment is
    the attitude of the IMU's nominal RFU axes relative to the vehicle, with the §8.0 angle
    conventions (pitch positive = IMU forward axis tilted up, yaw positive = IMU forward
    axis turned clockwise/right seen from above).

    Parameters
    ----------
    pitch_mis_deg, yaw_mis_deg, roll_mis_deg : float
        Misalignment angles [deg]. Defaults: the rtkx_drive_0708 README values.
    nominal : array_like (3, 3)
        Axis permutation from IMU axes to RFU (default: rtkx, x backward, z up).

    Returns
    -------
    numpy.ndarray (3, 3)
    """
    nominal = np.asarray(nominal, dtype=float)
    if nominal.shape != (3, 3) or not np.allclose(nominal @ nominal.T, np.eye(3), atol=1e-9):
        raise NavlabError("nominal body-to-vehicle matrix must be a 3x3 rotation; check its rows.")
    Cm = euler_to_dcm(np.radians(pitch_mis_deg), np.radians(roll_mis_deg), np.radians(yaw_mis_deg))
    return Cm @ nominal


def vehicle_tilt_from_static(f_b_mean_mps2, C_bv=None):
    """Vehicle roll and pitch [deg] implied by a static mean specific force.

    Parameters
    ----------
    f_b_mean_mps2 : array_like (3,)
        Mean static accelerometer output in the IMU body frame [m/s^2] (or any unit).
    C_bv : array_like (3, 3), optional
        Body-to-vehicle rotation (identity: body is RFU).

    Returns
    -------
    pitch_deg, roll_deg : float
        Static tilt of the vehicle frame; near zero for a level car if ``C_bv`` is right.
    """
    f = np.asarray(f_b_mean_mps2, dtype=float)
    fv = f if C_bv is None else np.asarray(C_bv, dtype=float) @ f
    n = np.linalg.norm(fv)
    return float(np.degrees(np.arcsin(fv[1] / n))), float(np.degrees(np.arctan2(-fv[0], fv[2])))


def triad_attitude(f_b_mean, heading_rad: float, forward_b=(0.0, 1.0, 0.0), f_n=None):
    """``C_b^n`` from the mean specific-force direction and a vehicle heading (TRIAD).

    The body direction of ``f_b_mean`` is mapped to the navigation direction of ``f_n``
    (default ENU up: a vehicle at rest); the part of the vehicle forward axis ``forward_b``
    (expressed in body) perpendicular to it is mapped to the heading ``heading_rad``
    (clockwise from north), likewise made perpendicular to ``f_n``.

    Parameters
    ----------
    f_b_mean : array_like (3,)
        Mean specific force in body (any unit).
    heading_rad : float
        Heading of the vehicle forward axis [rad].
    forward_b : array_like (3,)
        Vehicle forward axis in body coordinates (``C_bv.T @ [0, 1, 0]``).
    f_n : array_like (3,), optional
        The same mean specific force in ENU, ``a^n + (0, 0, g)`` when the vehicle accelerates
        (default ``(0, 0, 1)``: at rest).

    Returns
    -------
    numpy.ndarray (3, 3)
    """
    up_b = np.asarray(f_b_mean, dtype=float)
    up_b = up_b / np.linalg.norm(up_b)
    fw = np.asarray(forward_b, dtype=float)
    fw_h = fw - up_b * (up_b @ fw)
    if np.linalg.norm(fw_h) < 1e-3:
        raise NavlabError("forward axis is (almost) vertical in the static data; check the mounting matrix.")
    fw_h /= np.linalg.norm(fw_h)
    Bm = np.column_stack([np.cross(fw_h, up_b), fw_h, up_b])  # right, forward, up in body
    up_n = np.array([0.0, 0.0, 1.0]) if f_n is None else np.asarray(f_n, dtype=float) / np.linalg.norm(f_n)
    fw_n = np.array([np.sin(heading_rad), np.cos(heading_rad), 0.0])
    fw_n = fw_n - up_n * (up_n @ fw_n)
    fw_n /= np.linalg.norm(fw_n)
    Nm = np.column_stack([np.cross(fw_n, up_n), fw_n, up_n])
    return Nm @ Bm.T


@dataclass(frozen=True)
class AlignmentResult:
    """Result of a coarse static alignment.

    Attributes
    ----------
    C_bn : numpy.ndarray (3, 3)
        IMU body to ENU.
    pitch_deg, roll_deg, heading_deg : float
        VEHICLE attitude (RFU, through ``C_bv``) [deg].
    gyro_bias_radps : numpy.ndarray (3,)
        Mean static gyro output minus the Earth rate seen in body [rad/s].
    f_b_mean_mps2, f_b_std_mps2 : numpy.ndarray (3,)
        Mean and standard deviation of the static accelerometer output [m/s^2].
    w_b_std_radps : numpy.ndarray (3,)
        Standard deviation of the static gyro output [rad/s].
    accel_norm_minus_gravity_mps2 : float
        ``|mean f| - normal gravity`` [m/s^2]: accelerometer scale/bias indicator.
    n_samples : int
    """

    C_bn: np.ndarray
    pitch_deg: float
    roll_deg: float
    heading_deg: float
    gyro_bias_radps: np.ndarray
    f_b_mean_mps2: np.ndarray
    f_b_std_mps2: np.ndarray
    w_b_std_radps: np.ndarray
    accel_norm_minus_gravity_mps2: float
    n_samples: int


def align_static(f_b_mps2, w_b_radps, lat_rad: float, h_m: float, heading_rad: float, C_bv=None):
    """Coarse static alignment over samples recorded while the vehicle stands still.

    Parameters
    ----------
    f_b_mps2, w_b_radps : array_like (N, 3)
        Static IMU samples [m/s^2], [rad/s].
    lat_rad, h_m : float
        Position [rad], [m] (for gravity and Earth rate).
    heading_rad : float
        Vehicle heading [rad], clockwise from north (RTK course or user value).
    C_bv : array_like (3, 3), optional
        IMU body to vehicle RFU (identity: the IMU is RFU).

    Returns
    -------
    AlignmentResult
    """
    f = np.asarray(f_b_mps2, dtype=float)
    w = np.asarray(w_b_radps, dtype=float)
    if f.ndim != 2 or f.shape[1] != 3 or f.shape != w.shape or f.shape[0] < 10:
        raise NavlabError(
            "static alignment needs at least 10 IMU samples of shape (N, 3); give a longer static window."
        )
    C_bv = np.eye(3) if C_bv is None else np.asarray(C_bv, dtype=float)
    f_mean = f.mean(axis=0)
    g = float(normal_gravity(lat_rad, h_m))
    if not 0.5 * g < np.linalg.norm(f_mean) < 1.5 * g:
        raise NavlabError(
            f"mean static specific force is {np.linalg.norm(f_mean):.3g} m/s^2, not about {g:.2f}: "
            "the accelerometer must be in m/s^2 and the window static."
        )
    C_bn = triad_attitude(f_mean, heading_rad, C_bv.T @ np.array([0.0, 1.0, 0.0]))
    pitch, roll, heading = dcm_to_euler(C_bn @ C_bv.T)
    bias = w.mean(axis=0) - C_bn.T @ earth_rate_enu(lat_rad)
    return AlignmentResult(
        C_bn=C_bn,
        pitch_deg=float(np.degrees(pitch)),
        roll_deg=float(np.degrees(roll)),
        heading_deg=float(np.degrees(heading)),
        gyro_bias_radps=bias,
        f_b_mean_mps2=f_mean,
        f_b_std_mps2=f.std(axis=0),
        w_b_std_radps=w.std(axis=0),
        accel_norm_minus_gravity_mps2=float(np.linalg.norm(f_mean) - g),
        n_samples=int(f.shape[0]),
    )


def align_moving(
    f_b_mps2, w_b_radps, a_n_mps2, lat_rad: float, h_m: float, heading_rad: float, C_bv=None
) -> AlignmentResult:
    """Coarse alignment while the vehicle moves (no static segment to align on).

    Assumptions (stated, as the issue asks): over the averaging window (≈ 1 s) (1) the vehicle's
    acceleration is ``a_n_mps2``, the change of the GNSS velocity over the window (zero when
    only positions are known: then the tilt is only as good as a / g of the real acceleration);
    (2) the vehicle turns little, so the mean specific force in body is that of the mean
    attitude; (3) no side slip: the vehicle heading is the GNSS course ``heading_rad``. Roll and
    pitch then come from TRIAD with the mean specific force ``f^n = a^n + (0, 0, g)``. The gyro
    biases cannot be measured in motion: they are returned as zero (the caller's P0 says how
    uncertain that is).

    Parameters
    ----------
    f_b_mps2, w_b_radps : array_like (N, 3)
        IMU samples over the window [m/s^2], [rad/s].
    a_n_mps2 : array_like (3,)
        Mean ENU acceleration over the window [m/s^2].
    lat_rad, h_m : float
        Position (for gravity).
    heading_rad : float
        Vehicle heading (course over ground) [rad], clockwise from north.
    C_bv : array_like (3, 3), optional
        IMU body to vehicle RFU.

    Returns
    -------
    AlignmentResult
    """
    f = np.asarray(f_b_mps2, dtype=float)
    w = np.asarray(w_b_radps, dtype=float)
    if f.ndim != 2 or f.shape[1] != 3 or f.shape != w.shape or f.shape[0] < 2:
        raise NavlabError("an alignment in motion needs at least 2 IMU samples before the first epoch.")
    C_bv = np.eye(3) if C_bv is None else np.asarray(C_bv, dtype=float)
    g = float(normal_gravity(lat_rad, h_m))
    f_mean = f.mean(axis=0)
    f_n = np.asarray(a_n_mps2, dtype=float) + np.array([0.0, 0.0, g])
    C_bn = triad_attitude(f_mean, heading_rad, C_bv.T @ np.array([0.0, 1.0, 0.0]), f_n=f_n)
    pitch, roll, heading = dcm_to_euler(C_bn @ C_bv.T)
    return AlignmentResult(
        C_bn=C_bn,
        pitch_deg=float(np.degrees(pitch)),
        roll_deg=float(np.degrees(roll)),
        heading_deg=float(np.degrees(heading)),
        gyro_bias_radps=np.zeros(3),
        f_b_mean_mps2=f_mean,
        f_b_std_mps2=f.std(axis=0),
        w_b_std_radps=w.std(axis=0),
        accel_norm_minus_gravity_mps2=float(np.linalg.norm(f_mean) - np.linalg.norm(f_n)),
        n_samples=int(f.shape[0]),
    )


def course_heading(v_enu_mps):
    """Course over ground, clockwise from north [rad], from ENU velocities (..., 3) or (..., 2)."""
    v = np.asarray(v_enu_mps, dtype=float)
    return np.mod(np.arctan2(v[..., 0], v[..., 1]), 2.0 * np.pi)


def motion_start_time(t_s, v_enu_mps, speed_threshold_mps: float = 0.3, hold_s: float = 1.0):
    """First time the horizontal speed stays above a threshold for ``hold_s`` seconds.

    Parameters
    ----------
    t_s : array_like (N,)
        Epoch times [s].
    v_enu_mps : array_like (N, 3)
        Velocities [m/s] (e.g. RTK).
    speed_threshold_mps, hold_s : float
        Threshold [m/s] and how long it must hold [s].

    Returns
    -------
    float
        Time [s]; raises NavlabError if the vehicle never moves.
    """
    t = np.asarray(t_s, dtype=float)
    v = np.asarray(v_enu_mps, dtype=float)
    moving = np.hypot(v[:, 0], v[:, 1]) > speed_threshold_mps
    for i in np.flatnonzero(moving):
        j = np.searchsorted(t, t[i] + hold_s)
        if np.all(moving[i:j]) and j > i:
            return float(t[i])
    raise NavlabError(
        f"speed never exceeds {speed_threshold_mps} m/s; lower the threshold or check velocities."
    )
