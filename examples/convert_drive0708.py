r"""Worked example: convert a slice of rtklibexplorer's drive_0708 into navlab's generic CSV format.

The drive (../shared/data/rtkx_drive_0708, BSD-3-Clause, © 2025 rtklibexplorer) is a car with a
100 Hz MEMS IMU and a u-blox RTK receiver. This script turns it into the three files navlab reads
for YOUR OWN drive — imu.csv, gnss.csv, truth.csv — step by step, the way you would convert any
recording, and cuts it to start AT SPEED (everything before the car first exceeds ``--cut-speed``
m/s is dropped, so there is no static segment: navlab must start in motion).

    python examples/convert_drive0708.py --out /tmp/drive_moving
    python -m navlab run --scenario own-drive --set scenario.data_dir=/tmp/drive_moving \\
        --set scenario.mount_roll_deg=-6.8 --set scenario.mount_yaw_deg=95.4

Each step below says which question of the README ("Your own drive") it answers.

1. Units: the IMU logs g and deg/s; navlab wants m/s² (specific force, what an accelerometer
   measures: +9.81 m/s² upwards at rest, NOT the acceleration) and rad/s.
2. Time base: the IMU rows carry a millisecond counter; the RTKLIB time-tag file maps it to GPS
   time. The GNSS solution is in GPS time too. Both are written as ``t_s`` = seconds since the
   first GNSS epoch — any common origin works, it only has to be ONE time base. The data README's
   IMU offset (−0.20 s, navlab.data.loaders.RTKX_IMU_TIME_OFFSET_S) is applied here; for your own
   receiver, navlab prints the GNSS offset that best aligns the course with the yaw rate.
3. Axes: the IMU's own axes are written as they are (x backward, y right, z up on this car);
   the mounting rotation (roll −6.8°, pitch 0°, yaw +95.4°: the IMU's y axis points to the
   vehicle's right, its x axis backwards, tilted 6.8° about that y axis) is given to navlab with
   ``mount_*_deg`` (computed from the data README's mounting and printed at the end). Rotating the
   columns into the vehicle frame yourself (x right, y forward, z up) works as well; then leave
   the mounting at 0.
4. Heights: RTKLIB writes ELLIPSOIDAL heights (WGS 84), which is what navlab expects. A receiver
   that reports height above mean sea level (NMEA GGA) needs the geoid undulation added.
5. GNSS fixes and their σ: this drive has only an RTK receiver (cm level), which is used as the
   TRUTH. To stand in for an ordinary receiver, gnss.csv gets the RTK fixes at 1 Hz plus seeded
   noise of ``--sigma-m`` per axis (and ``--sigma-v`` on the velocities), and declares that σ in
   its ``sigma_n/e/u_m`` columns — as a receiver reporting its own accuracy would. With
   ``--clean`` the fixes are written unchanged (then add noise in navlab with ``add_noise``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

from navlab.data.loaders import (
    RTKX_DIR,
    RTKX_IMU_TIME_OFFSET_S,
    data_root,
    read_rtklib_pos,
    read_rtklib_tag,
)
from navlab.ins.align import RTKX_NOMINAL_C_BV, body_to_vehicle
from navlab.ins.earth import G0_MPS2, dcm_to_euler, radii
from navlab.ins.lc import velocity_lag_s


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--data", default=None, help="folder holding rtkx_drive_0708/ (default: navlab's data root)"
    )
    ap.add_argument("--out", required=True, help="output folder for imu.csv, gnss.csv, truth.csv")
    ap.add_argument("--cut-speed", type=float, default=5.0, help="drop the recording before this speed (m/s)")
    ap.add_argument(
        "--seconds", type=float, default=0.0, help="keep this many seconds after the cut (0: all)"
    )
    ap.add_argument("--sigma-m", type=float, default=3.0, help="noise added to the 1 Hz fixes, per axis (m)")
    ap.add_argument("--sigma-v", type=float, default=0.1, help="noise added to the velocities (m/s)")
    ap.add_argument("--seed", type=int, default=1, help="seed of that noise")
    ap.add_argument("--clean", action="store_true", help="write the 1 Hz RTK fixes without noise")
    return ap


def read_imu(src: Path, t0: float):
    """The IMU: g and deg/s plus a millisecond counter (steps 1 and 2): (t_s, f [m/s²], ω [rad/s])."""
    raw = np.loadtxt(src / "imu_1934.csv", delimiter=",")
    t_start, ticks = read_rtklib_tag(src / "imu_1934.csv.tag")
    ms = raw[:, 6]
    scale = (ticks[-1] / 1000.0) / ((ms[-1] - ms[0]) / 1000.0)  # the counter's clock vs GPS time
    t_imu = t_start + (ms - ms[0]) / 1000.0 * scale + RTKX_IMU_TIME_OFFSET_S - t0
    f = raw[:, 0:3] * G0_MPS2  # g -> m/s² (specific force)
    w = np.radians(raw[:, 3:6])  # deg/s -> rad/s
    return t_imu, f, w


def velocity_lag(fixed: pd.DataFrame) -> float:
    """How long RTKLIB's velocities lag its own positions (a property of the solution file, no
    truth involved; ≈ 0.12 s).
    """
    p_neu = np.c_[
        np.radians(fixed.lat_deg - fixed.lat_deg.iloc[0]) * 6.37e6,
        np.radians(fixed.lon_deg - fixed.lon_deg.iloc[0])
        * 6.37e6
        * np.cos(np.radians(fixed.lat_deg.iloc[0])),
        fixed.h_m,
    ]
    return velocity_lag_s(fixed.t_s.to_numpy(), p_neu, fixed[["ve_mps", "vn_mps", "vu_mps"]].to_numpy())


def degraded_fixes(fixed: pd.DataFrame, lag: float, a: argparse.Namespace) -> pd.DataFrame:
    """The fixes at whole seconds (1 Hz), degraded to an ordinary receiver (step 5).

    The velocities are read at t + ``lag`` so that they and the positions are on one time base,
    as a receiver's Doppler velocities usually are.
    """
    whole = fixed[np.isclose(fixed.t_s % 1.0, 0.0, atol=1e-3) | np.isclose(fixed.t_s % 1.0, 1.0, atol=1e-3)]
    whole = whole.copy()
    for c in ("vn_mps", "ve_mps", "vu_mps"):
        whole[c] = np.interp(whole.t_s + lag, fixed.t_s, fixed[c])
    rng = np.random.default_rng(a.seed)
    n = len(whole)
    s_p, s_v = (0.0, 0.0) if a.clean else (a.sigma_m, a.sigma_v)
    lat0 = np.radians(whole.lat_deg.iloc[0])
    R_M, R_N = radii(lat0, float(whole.h_m.iloc[0]))
    dn, de, du = (s_p * rng.standard_normal(n) for _ in range(3))
    gnss = pd.DataFrame(
        {
            "t_s": whole.t_s,
            "lat_deg": whole.lat_deg + np.degrees(dn / R_M),
            "lon_deg": whole.lon_deg + np.degrees(de / (R_N * np.cos(lat0))),
            "h_m": whole.h_m + du,
            "vn_mps": whole.vn_mps + s_v * rng.standard_normal(n),
            "ve_mps": whole.ve_mps + s_v * rng.standard_normal(n),
            "vu_mps": whole.vu_mps + s_v * rng.standard_normal(n),
        }
    )
    if not a.clean:
        for c in ("sigma_n_m", "sigma_e_m", "sigma_u_m"):
            gnss[c] = s_p
    return gnss


def write_files(out: Path, src: Path, header: str, tables: dict[str, pd.DataFrame]) -> None:
    """Each table as ``out/NAME`` below the provenance header, and the recording's licence beside them."""
    for name, df in tables.items():
        with open(out / name, "w", encoding="utf-8") as fh:
            fh.write(header)
            df.to_csv(fh, index=False, float_format="%.10g")
    lic = src / "LICENSE"
    if lic.is_file():
        (out / "LICENSE").write_text(lic.read_text(encoding="utf-8"), encoding="utf-8")


def print_next_steps(out: Path, sizes: tuple[int, int, int], t_cut: float, lag: float) -> None:
    """What was written, and the navlab command with the mounting angles (step 3: the IMU's
    attitude in the vehicle frame).
    """
    pitch, roll, yaw = (
        float(np.degrees(v)) for v in dcm_to_euler(body_to_vehicle(nominal=RTKX_NOMINAL_C_BV))
    )
    yaw = (yaw + 180.0) % 360.0 - 180.0
    print(f"wrote {out}/imu.csv ({sizes[0]} rows), gnss.csv ({sizes[1]}), truth.csv ({sizes[2]})")
    print(f"cut at t_s = {t_cut:.2f} s; the first 30 s end at t_s = {t_cut + 30:.2f} s")
    print(f"RTKLIB velocities read {lag:.2f} s later (their lag behind the positions)")
    print(
        "run: python -m navlab run --scenario own-drive "
        f"--set scenario.data_dir={out} --set scenario.mount_roll_deg={roll:.1f} "
        f"--set scenario.mount_pitch_deg={pitch:.1f} --set scenario.mount_yaw_deg={yaw:.1f}"
    )


def main(argv: list[str] | None = None) -> int:
    a = _parser().parse_args(argv)
    src = Path(a.data) if a.data else data_root()
    src = src / RTKX_DIR if (src / RTKX_DIR).is_dir() else src
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)

    # --- GNSS solution (RTKLIB .pos): GPS time, ellipsoidal heights, velocities ENU
    pos = read_rtklib_pos(src / "gnss_1934_sf.pos")
    t0 = float(pos.t_gpst_s.iloc[0])
    pos["t_s"] = pos.t_gpst_s - t0
    t_imu, f, w = read_imu(src, t0)

    # --- the cut: the first moment the car exceeds the cut speed (no static segment left)
    speed = np.hypot(pos.ve_mps, pos.vn_mps).to_numpy()
    t_cut = float(pos.t_s[np.argmax(speed > a.cut_speed)])
    t_end = t_cut + a.seconds if a.seconds > 0 else np.inf
    keep_i = (t_imu >= t_cut) & (t_imu <= t_end)
    imu = pd.DataFrame(
        np.column_stack([t_imu[keep_i], f[keep_i], w[keep_i]]),
        columns=["t_s", "f_x_mps2", "f_y_mps2", "f_z_mps2", "w_x_radps", "w_y_radps", "w_z_radps"],
    )

    # --- truth: the RTK-fixed epochs (Q = 1) at 4 Hz, with their velocities
    inside = (pos.t_s >= t_cut) & (pos.t_s <= t_end)
    fixed = pos[inside & (pos.q == 1)]
    truth = fixed[["t_s", "lat_deg", "lon_deg", "h_m", "vn_mps", "ve_mps", "vu_mps"]]

    # --- gnss: the fixes at whole seconds, degraded to an ordinary receiver (step 5)
    lag = velocity_lag(fixed)
    gnss = degraded_fixes(fixed, lag, a)

    header = (
        "# rtkx_drive_0708 (BSD-3-Clause, (c) 2025 rtklibexplorer), converted by "
        "examples/convert_drive0708.py; "
        f"t_s = GPS time - {t0:.3f} s; cut at {t_cut:.2f} s (first speed > {a.cut_speed:g} m/s)\n"
    )
    write_files(out, src, header, {"imu.csv": imu, "gnss.csv": gnss, "truth.csv": truth})
    print_next_steps(out, (len(imu), len(gnss), len(truth)), t_cut, lag)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
