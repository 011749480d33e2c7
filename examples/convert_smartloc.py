"""Worked example: write a smartLoc sequence in navlab's generic pseudorange CSV format.

The generic format is what you convert YOUR pseudoranges to (README "Your own pseudoranges");
this script shows it on the smartLoc Berlin recording (../shared/data/smartloc_berlin_pp,
CC BY-SA 4.0, TU Chemnitz), whose lines already hold everything the format needs:

* ``pseudoranges.csv`` — one row per satellite and epoch: ``t_s, sat_id, system, pseudorange_m,
  sat_x_m, sat_y_m, sat_z_m`` and the optional ``var_m2, elevation_deg, cn0_dbhz``. The
  pseudorange must already be corrected for the satellite clock and the atmosphere (smartLoc's
  are), and the satellite position is ECEF AT TRANSMIT TIME (navlab applies the Earth-rotation
  correction). ``system`` is written as a RINEX letter here (G GPS, R GLONASS, E Galileo, C BeiDou,
  J QZSS, S SBAS); smartLoc's numeric codes (1, 4, 8, 32, 16, 2) work as well.
* ``odometry.csv`` (optional) — ``t_s, speed_mps, yaw_rate_radps`` (counter-clockwise positive,
  the vehicle's up axis). Without it navlab uses a constant-velocity model.
* ``truth.csv`` (optional) — ``t_s, lat_deg, lon_deg, h_m`` (ellipsoidal) or ECEF ``x_m, y_m, z_m``.

    python examples/convert_smartloc.py --out /tmp/berlin_csv --seconds 60
    python -m navlab run --scenario own-pseudoranges --set scenario.data_dir=/tmp/berlin_csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

from navlab.data.loaders import SYSTEM_CODES, SYSTEM_LETTERS, load_pseudoranges
from navlab.ins.earth import ecef_to_geodetic


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=None, help="the smartLoc folder (default: the Berlin recording)")
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--seconds", type=float, default=0.0, help="keep this many seconds (0: all)")
    ap.add_argument("--no-odometry", action="store_true", help="leave odometry.csv out")
    ap.add_argument("--no-truth", action="store_true", help="leave truth.csv out")
    a = ap.parse_args(argv)
    rec = load_pseudoranges(a.data)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    t_end = rec.pr.t_s.min() + a.seconds if a.seconds > 0 else np.inf
    letter = {code: next(k for k, v in SYSTEM_LETTERS.items() if v == code) for code in SYSTEM_CODES}
    pr = rec.pr[rec.pr.t_s <= t_end].copy()
    pr["system"] = pr.system.map(letter)
    cols = ["t_s", "sat_id", "system", "pseudorange_m", "sat_x_m", "sat_y_m", "sat_z_m"]
    cols += ["var_m2", "elevation_deg", "cn0_dbhz"]
    pr[cols].to_csv(out / "pseudoranges.csv", index=False, float_format="%.15g")
    if rec.odom is not None and not a.no_odometry:
        rec.odom[rec.odom.t_s <= t_end].to_csv(out / "odometry.csv", index=False, float_format="%.15g")
    if rec.truth is not None and not a.no_truth:
        gt = rec.truth[rec.truth.t_s <= t_end]
        lat, lon, h = ecef_to_geodetic(gt[["x_m", "y_m", "z_m"]].to_numpy())
        pd.DataFrame(
            {"t_s": gt.t_s, "lat_deg": np.degrees(lat), "lon_deg": np.degrees(lon), "h_m": h}
        ).to_csv(out / "truth.csv", index=False, float_format="%.15g")
    print(f"wrote {out}: {len(pr)} pseudoranges, {pr.t_s.nunique()} epochs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
