"""Parsers for ``rtkx_drive_0708``, ``smartloc_berlin_pp`` and the generic CSV format.

Time
----
Every table has a ``t_s`` column: seconds from the start of the recording (first GNSS epoch for
the drives, the file's own time origin for smartLoc). ``DriveRecording.t0_gpst_s`` keeps the
absolute GPS time (s since 1970-01-01 without leap seconds) of ``t_s = 0``.

Generic format (what a user may upload)
---------------------------------------
A directory (or three uploaded files) with comma-separated values and a header line:

``imu.csv`` (required): ``t_s, f_x_mps2, f_y_mps2, f_z_mps2, w_x_radps, w_y_radps, w_z_radps`` —
time [s], specific force [m/s²] and angular rate [rad/s] in the VEHICLE frame x right, y
forward, z up (a level, parked vehicle reads f ≈ (0, 0, +9.8)).

``gnss.csv`` (required): ``t_s, lat_deg, lon_deg, h_m`` and optionally ``sigma_n_m, sigma_e_m,
sigma_u_m`` (1-σ position uncertainty) and ``vn_mps, ve_mps, vu_mps`` (velocity).

``truth.csv`` (optional): ``t_s, lat_deg, lon_deg, h_m`` — reference positions for the errors.

Lines starting with ``#`` are comments. Times are seconds and increase strictly (a repeated time
stamp is refused, and so are times in ms/µs/ns: :func:`check_time_unit` names the unit).
"""

from __future__ import annotations

import calendar
import csv
import io
import math
import os
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from navlab import memory
from navlab.errors import NavlabError
from navlab.ins.align import RTKX_NOMINAL_C_BV, body_to_vehicle
from navlab.ins.earth import G0_MPS2
from navlab.io import read_text

#: Environment variable naming the data directory (overrides ../shared/data).
ENV_VAR = "NAVLAB_DATA"

RTKX_DIR = "rtkx_drive_0708"
SMARTLOC_DIR = "smartloc_berlin_pp"
#: Constant IMU time offset of the rtkx drive. The data README's −0.10 s aligns the yaw rate with
#: the course of the RTK *velocities*; those lag the RTK *positions* by ≈ 0.12 s (velocity vs
#: centred position differences of the .pos file: rms 0.10 m/s at lag 0, 0.03 m/s at 0.10–0.15 s).
#: The aiding is made from the positions, so the IMU is aligned with them: the yaw rate matches
#: the course rate of differenced positions best at −0.20 s (rms 0.009 vs 0.019 rad/s at −0.10 s),
#: and the 1-s prediction error of the INS between RTK fixes halves (8 → 4.5 cm).
#: tests/unit/test_drive0708.py re-measures both from the recording.
RTKX_IMU_TIME_OFFSET_S = -0.20

RTKX_SOURCE = (
    "rtkx_drive_0708: public repository rtklibexplorer/GNSS_IMU, folder data/drive_0708 "
    "(BSD-3-Clause, © 2025 rtklibexplorer). Car drive near Boulder CO: MEMS IMU at 100 Hz "
    "and a u-blox RTK solution (cm level) used as the truth."
)
SMARTLOC_SOURCE = (
    "smartloc_berlin_pp: the smartLoc dataset (TU Chemnitz; P. Reisdorf, T. Pfeifer, J. Breßler, "
    "S. Bauer, P. Weissig, S. Lange), as distributed in the public repository TUC-ProAut/libRSF, "
    "folder datasets/smartLoc; licence CC BY-SA 4.0. Berlin Potsdamer Platz: GPS + GLONASS "
    "pseudoranges, odometry, NovAtel SPAN ground truth."
)


def repo_root() -> Path:
    """The repository root (the directory holding the ``navlab`` package)."""
    return Path(__file__).resolve().parents[2]


def data_root(path: str | os.PathLike | None = None) -> Path:
    """Where the recordings live: ``path``, else ``$NAVLAB_DATA``, else ``<repo>/../shared/data``."""
    if path is not None and str(path) != "":
        return Path(path).expanduser()
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env).expanduser()
    return repo_root().parent / "shared" / "data"


def _recording_dir(name: str, path: str | os.PathLike | None) -> Path:
    """The folder of recording ``name``; ``path`` may be the data root or the folder itself."""
    root = data_root(path)
    if (root / name).is_dir():
        return root / name
    if root.name == name and root.is_dir():
        return root
    raise NavlabError(
        f"recording folder '{name}' not found under {root}; set {ENV_VAR}=/path/to/data (the "
        f"directory holding {name}/) or pass it: --set scenario.data_dir=/path/to/data"
    )


def is_offered(data_dir: str | os.PathLike, offered: Sequence[str | os.PathLike] = ()) -> bool:
    """Whether ``data_dir`` lies inside the data root or one of the ``offered`` folders.

    Symbolic links and ``..`` are resolved first, so a link inside the data root that points
    elsewhere is not offered.
    """
    try:
        p = Path(data_dir).expanduser().resolve()
        roots = [data_root().resolve(), *(Path(o).resolve() for o in offered)]
    except (OSError, RuntimeError, ValueError, TypeError):
        return False
    return any(p == r or r in p.parents for r in roots)


def check_offered(data_dir: str | os.PathLike | None, offered: Sequence[str | os.PathLike] = ()) -> None:
    """Refuse a ``data_dir`` from outside (a browser) that the deployment does not offer.

    A configuration loaded in the app may name only the deployment's data root (``NAVLAB_DATA`` or
    ``../shared/data``; an empty ``data_dir`` means it) and the session's own uploads
    (``offered``). The message names neither the folder nor anything in it. The CLI, run by a
    local user, does not call this: it may name any folder.
    """
    if data_dir in (None, "") or is_offered(str(data_dir), offered):
        return
    raise NavlabError(
        "scenario_params.data_dir names a folder this server does not offer: in the app a "
        "configuration can use only the recordings the deployment provides (leave data_dir "
        "empty) or files uploaded in this session (Real data page, 'Upload your own drive'); "
        "run other folders with the command line: python -m navlab run --config FILE"
    )


# ---------------------------------------------------------------------------- parsing helpers
Range = tuple[float, float, str]


def _read_text(path: Path) -> str:
    """The file's text through navlab's one decoding path (:func:`navlab.io.read_text`)."""
    if not path.exists():
        raise NavlabError(
            f"{path}: file not found; check the data directory ({ENV_VAR} or --set scenario.data_dir=...)"
        )
    text = read_text(path)
    if not text.strip():
        raise NavlabError(f"{path}: the file is empty; give a file with data rows")
    return text


def _parse_rows(
    path: Path,
    names: tuple[str, ...],
    *,
    sep: str | None = ",",
    keyword: str | None = None,
    skip: Callable[[str], bool] = lambda s: s.startswith(("#", "%")),
    ranges: dict[str, Range] | None = None,
    first_line: int = 1,
    lines: list[str] | None = None,
) -> np.ndarray:
    """Parse numeric rows of ``len(names)`` columns with exact line/column error messages.

    ``keyword``: only lines whose first field equals it are parsed (the field is dropped).
    Extra trailing columns are ignored. Returns (N, len(names)) float64.
    """
    if lines is None:
        lines = _read_text(path).splitlines()
    ncol = len(names)
    rows: list[list[float]] = []
    for i, line in enumerate(lines, start=first_line):
        s = line.strip()
        if not s or skip(s):
            continue
        parts = s.split(sep) if sep is not None else s.split()
        if keyword is not None:
            if parts[0] != keyword:
                continue
            parts = parts[1:]
        parts = [p.strip() for p in parts]
        if len(parts) < ncol:
            raise NavlabError(
                f"{path}: line {i} has {len(parts)} column(s), expected {ncol} "
                f"({', '.join(names)}); the file is truncated or not in this format"
            )
        row = []
        for j, name in enumerate(names):
            try:
                v = float(parts[j])
            except ValueError:
                raise NavlabError(
                    f"{path}: line {i}, column {j + 1} ({name}) is {parts[j][:30]!r}, not a number; "
                    "fix or delete that line"
                ) from None
            if not math.isfinite(v):
                raise NavlabError(
                    f"{path}: line {i}, column {j + 1} ({name}) is {parts[j]!r}; "
                    "NaN/inf values are not allowed — fix or delete that line"
                )
            if ranges and name in ranges:
                lo, hi, unit = ranges[name]
                if not lo <= v <= hi:
                    raise NavlabError(
                        f"{path}: line {i}, column {j + 1} ({name}) = {v:g} is outside the "
                        f"plausible range [{lo:g}, {hi:g}] {unit}; check the units or fix that line"
                    )
            row.append(v)
        rows.append(row)
    if not rows:
        what = f"'{keyword}' lines" if keyword else "data rows"
        raise NavlabError(f"{path}: no {what} found; the file is empty or not in this format")
    return np.asarray(rows, dtype=float)


def _check_increasing(path: Path, t: np.ndarray, what: str = "time", strict: bool = False) -> None:
    """Refuse times that go backwards (and, ``strict``, a time stamp given twice)."""
    d = np.diff(t)
    bad = np.flatnonzero(d < 0)
    if bad.size:
        raise NavlabError(
            f"{path}: {what} goes backwards at data row {bad[0] + 2} ({t[bad[0]]:.3f} -> "
            f"{t[bad[0] + 1]:.3f}); sort the rows by time"
        )
    same = np.flatnonzero(d == 0) if strict else ()
    if len(same):
        i = int(same[0])
        many = f"{len(same)} of {len(t)} rows repeat" if len(same) > 1 else "one row repeats"
        raise NavlabError(
            f"{path}: data rows {i + 1} and {i + 2} have the same {what} ({t[i]:.10g}; {many} the time "
            "of the row before): each row needs its own time stamp — delete rows written twice, or give "
            "a continuous time (a leap second written as a repeated second: use GPS time)"
        )


# ---------------------------------------------------------------------------- drives
@dataclass(frozen=True, eq=False)
class DriveRecording:
    """An IMU + GNSS (+ truth) recording for the loosely coupled INS/GNSS scenario.

    Attributes
    ----------
    name : recording name.
    imu : DataFrame ``t_s, f_x_mps2, f_y_mps2, f_z_mps2, w_x_radps, w_y_radps, w_z_radps``
        (IMU body axes) and ``repeated`` (bool: identical to the previous sample).
    gnss : DataFrame ``t_s, lat_deg, lon_deg, h_m, q, sigma_n_m, sigma_e_m, sigma_u_m,
        vn_mps, ve_mps, vu_mps`` (NaN where a column is absent).
    truth : DataFrame ``t_s, lat_deg, lon_deg, h_m`` or None.
    C_bv : (3, 3) rotation IMU body -> vehicle (x right, y forward, z up).
    t0_gpst_s : absolute GPS time of t_s = 0 (s since 1970, no leap seconds), NaN if unknown.
    source : provenance and licence statement.
    """

    name: str
    imu: pd.DataFrame
    gnss: pd.DataFrame
    truth: pd.DataFrame | None
    C_bv: np.ndarray
    t0_gpst_s: float
    source: str

    @property
    def duration_s(self) -> float:
        return float(self.gnss.t_s.iloc[-1] - self.gnss.t_s.iloc[0])


IMU_COLS = ("f_x_mps2", "f_y_mps2", "f_z_mps2", "w_x_radps", "w_y_radps", "w_z_radps")
GNSS_COLS = (
    "t_s",
    "lat_deg",
    "lon_deg",
    "h_m",
    "q",
    "sigma_n_m",
    "sigma_e_m",
    "sigma_u_m",
    "vn_mps",
    "ve_mps",
    "vu_mps",
)


def read_rtklib_tag(path: Path) -> tuple[float, np.ndarray]:
    """RTKLIB demo5 time-tag file: (start time [s since 1970, GPST], tick_ms records (N,))."""
    if not path.is_file():
        raise NavlabError(f"{path}: file not found (the IMU time-tag file must sit next to the CSV)")
    b = path.read_bytes()
    if len(b) < 84 or not b[:7] == b"TIMETAG":
        raise NavlabError(
            f"{path}: not an RTKLIB time-tag file (it must start with 'TIMETAG' and hold a 76-byte "
            "header plus 8-byte records); use the .tag file written with the IMU log"
        )
    _tick_f, t_start, frac = struct.unpack("<IId", b[60:76])
    if (len(b) - 76) % 8:
        raise NavlabError(
            f"{path}: truncated after byte {len(b) - (len(b) - 76) % 8}; "
            "the records are 8 bytes each — use an intact copy"
        )
    rec = np.frombuffer(b[76:], dtype="<u4").reshape(-1, 2)
    ticks = rec[:, 0].astype(float)
    if not math.isfinite(frac) or not 0 <= frac < 1 or np.any(np.diff(ticks) < 0):
        raise NavlabError(
            f"{path}: corrupt header or tick records (fraction {frac!r}); use an intact copy of the tag file"
        )
    return float(t_start) + float(frac), ticks


def read_rtklib_pos(path: Path) -> pd.DataFrame:
    """RTKLIB .pos solution (GPST date/time, lat/lon/h, Q, ns, σ's, velocities)."""
    lines = _read_text(path).splitlines()
    t_abs: list[float] = []
    body: list[str] = []
    first = None
    for i, line in enumerate(lines, start=1):
        s = line.strip()
        if not s or s.startswith("%"):
            continue
        parts = s.split()
        try:
            ymd = [int(v) for v in parts[0].split("/")]
            hh, mm, ss = parts[1].split(":")
            sec = float(ss)
            t = calendar.timegm((ymd[0], ymd[1], ymd[2], int(hh), int(mm), 0)) + sec
        except (ValueError, IndexError):
            raise NavlabError(
                f"{path}: line {i}, columns 1-2 must be 'YYYY/MM/DD hh:mm:ss.sss' (GPST), got "
                f"{' '.join(parts[:2])[:40]!r}; output the solution with time format 'yyyy/mm/dd'"
            ) from None
        if first is None:
            first = i
        t_abs.append(t)
        body.append(" ".join(parts[2:]))
    if not body:
        raise NavlabError(f"{path}: no solution epochs found (only header lines)")
    names = (
        "lat_deg",
        "lon_deg",
        "h_m",
        "q",
        "ns",
        "sdn_m",
        "sde_m",
        "sdu_m",
        "sdne_m",
        "sdeu_m",
        "sdun_m",
        "age_s",
        "ratio",
        "vn_mps",
        "ve_mps",
        "vu_mps",
    )
    ranges = {
        "lat_deg": (-90.0, 90.0, "deg"),
        "lon_deg": (-180.0, 360.0, "deg"),
        "h_m": (-1000.0, 1e5, "m"),
        "q": (0.0, 7.0, ""),
        "sdn_m": (0.0, 1e4, "m"),
        "sde_m": (0.0, 1e4, "m"),
        "sdu_m": (0.0, 1e4, "m"),
        "vn_mps": (-500.0, 500.0, "m/s"),
        "ve_mps": (-500.0, 500.0, "m/s"),
        "vu_mps": (-500.0, 500.0, "m/s"),
    }
    # line numbers: body lines are exactly the non-header lines in order
    data_lines = [ln for ln in lines if ln.strip() and not ln.strip().startswith("%")]
    idx = [i for i, ln in enumerate(lines, start=1) if ln.strip() and not ln.strip().startswith("%")]
    arr = np.empty((len(body), len(names)))
    for r, (i, _ln) in enumerate(zip(idx, data_lines, strict=True)):
        arr[r] = _parse_rows(path, names, sep=None, ranges=ranges, lines=[body[r]], first_line=i)[0]
    t = np.asarray(t_abs)
    _check_increasing(path, t)
    df = pd.DataFrame(arr, columns=names)
    df.insert(0, "t_gpst_s", t)
    return df


def rtkx_drive_0708(path: str | os.PathLike | None = None) -> DriveRecording:
    """Load the rtkx_drive_0708 car drive (100 Hz MEMS IMU, RTKLIB time tags, RTK solution).

    IMU rows are converted from g and deg/s to m/s² and rad/s; their times follow the data
    README: ``t0 + (ms_i − ms_0)/1000 · (last_tick/1000)/((ms_N − ms_0)/1000)``, plus the
    constant offset :data:`RTKX_IMU_TIME_OFFSET_S` (−0.20 s, aligned with the RTK positions).
    ≈2 % of IMU rows repeat the previous reading (new counter, same values); they are kept and
    marked in ``imu.repeated``. The truth is the RTK-fixed part (Q = 1) of the solution.
    """
    d = _recording_dir(RTKX_DIR, path)
    f_imu = d / "imu_1934.csv"
    lim_g, lim_w = 16.0, 2000.0
    raw = _parse_rows(
        f_imu,
        ("ax_g", "ay_g", "az_g", "gx_dps", "gy_dps", "gz_dps", "ms"),
        ranges={
            "ax_g": (-lim_g, lim_g, "g"),
            "ay_g": (-lim_g, lim_g, "g"),
            "az_g": (-lim_g, lim_g, "g"),
            "gx_dps": (-lim_w, lim_w, "deg/s"),
            "gy_dps": (-lim_w, lim_w, "deg/s"),
            "gz_dps": (-lim_w, lim_w, "deg/s"),
            "ms": (0.0, 2.0**32, "ms"),
        },
    )
    _check_increasing(f_imu, raw[:, 6], "the millisecond counter (column 7)")
    if raw.shape[0] < 100:
        raise NavlabError(f"{f_imu}: only {raw.shape[0]} IMU rows; the file is truncated")
    t_start, ticks = read_rtklib_tag(d / "imu_1934.csv.tag")
    ms = raw[:, 6]
    span = (ms[-1] - ms[0]) / 1000.0
    if span <= 0:
        raise NavlabError(f"{f_imu}: the millisecond counter does not advance")
    scale = (ticks[-1] / 1000.0) / span
    if not 0.9 < scale < 1.1:
        raise NavlabError(
            f"{d / 'imu_1934.csv.tag'}: its last tick ({ticks[-1]:.0f} ms) does not match the IMU "
            f"span ({span:.1f} s); the tag file belongs to another log"
        )
    t_imu_abs = t_start + (ms - ms[0]) / 1000.0 * scale + RTKX_IMU_TIME_OFFSET_S
    pos = read_rtklib_pos(d / "gnss_1934_sf.pos")
    t0 = float(pos.t_gpst_s.iloc[0])
    imu = pd.DataFrame(np.column_stack([raw[:, 0:3] * G0_MPS2, np.radians(raw[:, 3:6])]), columns=IMU_COLS)
    imu.insert(0, "t_s", t_imu_abs - t0)
    imu["repeated"] = np.r_[False, np.all(raw[1:, :6] == raw[:-1, :6], axis=1)]
    gnss = pd.DataFrame(
        {
            "t_s": pos.t_gpst_s - t0,
            "lat_deg": pos.lat_deg,
            "lon_deg": pos.lon_deg,
            "h_m": pos.h_m,
            "q": pos.q.astype(int),
            "sigma_n_m": pos.sdn_m,
            "sigma_e_m": pos.sde_m,
            "sigma_u_m": pos.sdu_m,
            "vn_mps": pos.vn_mps,
            "ve_mps": pos.ve_mps,
            "vu_mps": pos.vu_mps,
        }
    )
    truth = gnss.loc[gnss.q == 1, ["t_s", "lat_deg", "lon_deg", "h_m", "vn_mps", "ve_mps", "vu_mps"]]
    truth = truth.reset_index(drop=True)
    if len(truth) < 2:
        raise NavlabError(f"{d / 'gnss_1934_sf.pos'}: fewer than 2 RTK-fixed (Q=1) epochs")
    return DriveRecording(
        name=RTKX_DIR,
        imu=imu,
        gnss=gnss,
        truth=truth,
        C_bv=body_to_vehicle(nominal=RTKX_NOMINAL_C_BV),
        t0_gpst_s=t0,
        source=RTKX_SOURCE,
    )


# ---------------------------------------------------------------------------- generic CSV
def _read_header_csv(
    path: Path,
    required: tuple[str, ...],
    optional: tuple[str, ...],
    ranges: dict[str, Range],
    lines: list[str] | None = None,
    *,
    strict: bool = False,
) -> pd.DataFrame:
    """A CSV with a header line naming the columns (``#`` comments before or between rows).

    The data rows are parsed at C speed (:func:`_fast_rows`) when the file is plain; anything
    unusual, and every problem, goes to the line-by-line :func:`_parse_rows`, which names the line.
    ``strict``: times must increase strictly (one row per time stamp).
    """
    text = None
    if lines is None:
        text = _read_text(path)
        if _plain(text):  # find the header without splitting the whole file into lines
            hdr_i, pos = 0, 0
            while True:
                end = text.find("\n", pos)
                stop = len(text) if end < 0 else end
                line = text[pos:stop]
                if line.strip() and not line.lstrip().startswith("#"):
                    break
                if end < 0:
                    line = ""  # no header line
                    break
                hdr_i, pos = hdr_i + 1, end + 1
            head = [*([""] * hdr_i), line]
            body = text[stop + 1 :]
        else:
            lines = text.splitlines()
    if lines is not None:
        head, body = lines, None
    hdr_i = next((i for i, ln in enumerate(head) if ln.strip() and not ln.lstrip().startswith("#")), None)
    if hdr_i is None:
        raise NavlabError(
            f"{path}: no header line; the first line must name the columns ({', '.join(required)})"
        )
    if ";" in head[hdr_i] and "," not in head[hdr_i]:
        raise NavlabError(
            f"{path}: line {hdr_i + 1} (header) separates columns with ';'; save the file with "
            "commas between columns and '.' as the decimal point"
        )
    header = [h.strip().strip('"').strip() for h in head[hdr_i].split(",")]
    missing = [c for c in required if c not in header]
    if missing:
        raise NavlabError(
            f"{path}: line {hdr_i + 1} (header) lacks column(s) {', '.join(missing)}; the header "
            f"must contain {', '.join(required)} (optional: {', '.join(optional) or 'none'})"
        )
    try:
        float(header[0])
        raise NavlabError(f"{path}: line {hdr_i + 1} is numbers, not a header; add a header line")
    except ValueError:
        pass
    arr = _fast_rows(body, tuple(header), ranges) if body is not None else None
    if arr is None:
        arr = _parse_rows(
            path,
            tuple(header),
            lines=body.splitlines() if body is not None else head[hdr_i + 1 :],
            first_line=hdr_i + 2,
            ranges=ranges,
            skip=lambda s: s.startswith("#"),
        )
    del text, body
    df = pd.DataFrame(arr, columns=header)
    keep = [c for c in (*required, *optional) if c in df.columns]
    df = df[keep].copy()
    _check_increasing(path, df.t_s.to_numpy(), strict=strict)
    return df


#: Line breaks of str.splitlines other than "\n" and "\r\n": a file holding one is read line by line.
_ODD_BREAKS = ("\v", "\f", "\x1c", "\x1d", "\x1e", "\x85", "\u2028", "\u2029")


def _plain(text: str) -> bool:
    """Whether ``text`` breaks lines only with LF or CR LF (as str.splitlines would)."""
    return text.count("\r") == text.count("\r\n") and not any(c in text for c in _ODD_BREAKS)


#: pandas' float parsing as exact as Python's float(): "round_trip" before pandas 3 (whose default
#: is exact and which deprecates the option).
_EXACT = {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}


def _fast_rows(body: str, names: tuple[str, ...], ranges: dict[str, Range]) -> np.ndarray | None:
    """The data rows of a plain comma-separated ``body`` at C speed (pandas' parser), or None.

    None (read it line by line instead: :func:`_parse_rows` names the line at fault) when the text
    holds a comment or anything :func:`_parse_rows` would refuse or read otherwise: a row with
    more or fewer columns than ``names``, a value that is not a plain number (quotes, blanks,
    "NA"), NaN/inf, or a value outside ``ranges``. Values are parsed exactly (:data:`_EXACT`), so
    an accepted file gives the numbers of the line by line parse (tests/unit/test_csv_fuzz.py
    checks it on random files).
    """
    if "#" in body or not _plain(body):
        return None
    try:
        arr = pd.read_csv(
            io.BytesIO(body.encode("utf-8")),
            header=None,
            dtype=np.float64,
            **_EXACT,
            quoting=csv.QUOTE_NONE,
            na_filter=False,
            skip_blank_lines=True,
            engine="c",
        ).to_numpy()
    except (ValueError, OverflowError, TypeError, pd.errors.ParserError):
        return None
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] != len(names) or not np.isfinite(arr).all():
        return None
    for j, name in enumerate(names):
        if name in ranges:
            lo, hi, _ = ranges[name]
            if not ((arr[:, j] >= lo) & (arr[:, j] <= hi)).all():
                return None
    return arr


_POS_RANGES: dict[str, Range] = {
    "lat_deg": (-90.0, 90.0, "deg"),
    "lon_deg": (-180.0, 360.0, "deg"),
    "h_m": (-1000.0, 1e5, "m"),
    "sigma_n_m": (0.0, 1e4, "m"),
    "sigma_e_m": (0.0, 1e4, "m"),
    "sigma_u_m": (0.0, 1e4, "m"),
    "vn_mps": (-500.0, 500.0, "m/s"),
    "ve_mps": (-500.0, 500.0, "m/s"),
    "vu_mps": (-500.0, 500.0, "m/s"),
}


#: Sample intervals [s] an IMU (5 Hz – 10 kHz) and a GNSS receiver (0.02 – 100 Hz) can have: the
#: time unit of a drive is judged from them (:func:`check_time_unit`).
IMU_DT_S = (1e-4, 0.2)
GNSS_DT_S = (0.01, 50.0)
TIME_UNITS = (("seconds", 1.0), ("milliseconds", 1e3), ("microseconds", 1e6), ("nanoseconds", 1e9))
#: Bytes held per byte of a CSV while it is read (the file's bytes, its text and the parser's
#: copy) and per number of its rows (the parsed array, the table and the INS's copies of them).
READ_BYTES_PER_BYTE, READ_BYTES_PER_VALUE = 3, 48


def check_read_size(path: Path, ncol: int) -> None:
    """Refuse, before reading it, a CSV whose reading would not fit the memory budget.

    The rows are estimated from the file's size and the length of its first lines; the message
    gives the estimate, the budget and what to change.
    """
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            sample = f.read(1 << 16)
    except OSError:
        return  # reading it says what is wrong
    rows = size * max(sample.count(b"\n"), 1) / max(len(sample), 1)
    need = READ_BYTES_PER_BYTE * size + READ_BYTES_PER_VALUE * rows * ncol
    limit = memory.budget_bytes()
    if need > limit:
        raise NavlabError(
            f"{path}: {memory.fmt_bytes(size)}, about "
            + (f"{rows / 1e6:.3g} million" if rows >= 1e6 else f"{rows:,.0f}")
            + " rows: reading it would hold "
            f"about {memory.fmt_bytes(need)}, more than the memory budget of {memory.fmt_bytes(limit)} "
            f"({memory.budget_source()}); cut the recording into shorter parts, or raise the budget "
            f"({memory.ENV})"
        )


def check_time_unit(t_imu: np.ndarray, t_gnss: np.ndarray, names: str) -> None:
    """Refuse times that are not in seconds, naming the unit they seem to be in.

    The unit is judged from the median sample intervals: in seconds they must be an IMU's
    (:data:`IMU_DT_S`) and a receiver's (:data:`GNSS_DT_S`); when they are not, but would be in
    milliseconds, microseconds or nanoseconds, that unit is named.
    """
    dt_i, dt_g = float(np.median(np.diff(t_imu))), float(np.median(np.diff(t_gnss)))

    def fits(per_s: float) -> bool:
        return IMU_DT_S[0] <= dt_i / per_s <= IMU_DT_S[1] and GNSS_DT_S[0] <= dt_g / per_s <= GNSS_DT_S[1]

    if fits(1.0):
        return
    for unit, per_s in TIME_UNITS[1:]:
        if fits(per_s):
            raise NavlabError(
                f"{names}: t_s must be seconds, but it looks like {unit}: the IMU samples are {dt_i:.4g} "
                f"apart and the GNSS fixes {dt_g:.4g} (in {unit}: an IMU at {per_s / dt_i:.4g} Hz, fixes at "
                f"{per_s / dt_g:.4g} Hz); divide t_s by {per_s:.0e} in every file"
            )
    for what, dt, (lo, hi), rate in (
        ("IMU samples", dt_i, IMU_DT_S, "an IMU"),
        ("GNSS fixes", dt_g, GNSS_DT_S, "fixes"),
    ):
        for unit, per_s in TIME_UNITS[1:]:  # one file in another unit than the other
            if not lo <= dt <= hi and lo <= dt / per_s <= hi:
                raise NavlabError(
                    f"{names}: t_s must be seconds in every file, but the {what} are {dt:.4g} apart, "
                    f"which looks like {unit} ({rate} at {per_s / dt:.4g} Hz); divide that file's t_s by "
                    f"{per_s:.0e}"
                )


def load_generic(
    imu_csv: str | os.PathLike,
    gnss_csv: str | os.PathLike,
    truth_csv: str | os.PathLike | None = None,
    name: str = "user upload",
) -> DriveRecording:
    """Load the generic CSV format (see the module docstring for the columns and units)."""
    imu_ranges = {c: (-160.0, 160.0, "m/s²") for c in IMU_COLS[:3]}
    imu_ranges.update(
        {c: (-35.0, 35.0, "rad/s (a value this large usually means deg/s)") for c in IMU_COLS[3:]}
    )
    files = [Path(imu_csv), Path(gnss_csv), *([Path(truth_csv)] if truth_csv is not None else [])]
    for f, ncol in zip(files, (7, 10, 7), strict=False):
        check_read_size(f, ncol)
    imu = _read_header_csv(Path(imu_csv), ("t_s", *IMU_COLS), (), imu_ranges, strict=True)
    if len(imu) < 100:
        raise NavlabError(f"{imu_csv}: only {len(imu)} IMU rows; give at least 100 samples")
    fz = np.linalg.norm(imu[list(IMU_COLS[:3])].to_numpy().mean(axis=0))
    if not 5.0 < fz < 15.0:
        raise NavlabError(
            f"{imu_csv}: the mean specific force has magnitude {fz:.3g}, not ≈ 9.8 m/s² (gravity); "
            "give f_*_mps2 in m/s² (multiply g by 9.80665)"
        )
    imu["repeated"] = np.r_[False, np.all(np.diff(imu[list(IMU_COLS)].to_numpy(), axis=0) == 0, axis=1)]
    opt = ("sigma_n_m", "sigma_e_m", "sigma_u_m", "vn_mps", "ve_mps", "vu_mps")
    gnss = _read_header_csv(
        Path(gnss_csv), ("t_s", "lat_deg", "lon_deg", "h_m"), opt, _POS_RANGES, strict=True
    )
    if len(gnss) < 3:
        raise NavlabError(f"{gnss_csv}: only {len(gnss)} GNSS rows; give at least 3 epochs")
    for c in opt:
        if c not in gnss.columns:
            gnss[c] = np.nan
    gnss["q"] = 0
    gnss = gnss[list(GNSS_COLS)]
    check_time_unit(imu.t_s.to_numpy(), gnss.t_s.to_numpy(), f"{imu_csv} and {gnss_csv}")
    if imu.t_s.iloc[0] > gnss.t_s.iloc[-1] or imu.t_s.iloc[-1] < gnss.t_s.iloc[0]:
        raise NavlabError(f"{imu_csv} and {gnss_csv} do not overlap in time; use one time base (t_s)")
    truth = None
    if truth_csv is not None:
        truth = _read_header_csv(
            Path(truth_csv),
            ("t_s", "lat_deg", "lon_deg", "h_m"),
            ("vn_mps", "ve_mps", "vu_mps"),
            _POS_RANGES,
            strict=True,
        )
        if len(truth) < 2:
            raise NavlabError(
                f"{truth_csv}: only {len(truth)} truth row(s); give at least 2, or leave the file out"
            )
        tt, tg = truth.t_s.to_numpy(), gnss.t_s.to_numpy()
        if tt[0] > tg[-1] or tt[-1] < tg[0]:
            unit = next(
                (u for u, per_s in TIME_UNITS[1:] if tt[0] / per_s <= tg[-1] and tt[-1] / per_s >= tg[0]),
                None,
            )
            raise NavlabError(
                f"{truth_csv} and {gnss_csv} do not overlap in time"
                + (f" (the truth's t_s looks like {unit}, not seconds)" if unit else "")
                + "; give t_s in seconds on the GNSS's time base"
            )
    return DriveRecording(
        name=name,
        imu=imu,
        gnss=gnss.reset_index(drop=True),
        truth=truth,
        C_bv=np.eye(3),
        t0_gpst_s=float("nan"),
        source=f"{name}: user-provided files (generic navlab CSV format)",
    )


def load_drive(data_dir: str | os.PathLike | None = None) -> DriveRecording:
    """``rtkx_drive_0708`` from the data root, or a generic-format folder (imu.csv, gnss.csv[, truth.csv])."""
    if data_dir:
        d = Path(data_dir).expanduser()
        if (d / "imu.csv").exists() or (d / "gnss.csv").exists():
            truth = d / "truth.csv"
            return load_generic(d / "imu.csv", d / "gnss.csv", truth if truth.exists() else None, name=d.name)
    return rtkx_drive_0708(data_dir)


# ---------------------------------------------------------------------------- pseudoranges
#: smartLoc's satellite-system codes (its readme: 1 GPS, 2 SBAS, 4 GLONASS, 8 Galileo, 16 QZSS,
#: 32 BeiDou); the generic CSV also takes the RINEX letters.
SYSTEM_CODES = {1: "GPS", 2: "SBAS", 4: "GLONASS", 8: "Galileo", 16: "QZSS", 32: "BeiDou"}
SYSTEM_LETTERS = {"G": 1, "S": 2, "R": 4, "E": 8, "J": 16, "C": 32}


@dataclass(frozen=True, eq=False)
class PseudorangeRecording:
    """Pseudoranges, odometry and ground truth (smartLoc files or the generic pseudorange CSV).

    Attributes
    ----------
    pr : DataFrame ``t_s, pseudorange_m, var_m2, sat_x_m, sat_y_m, sat_z_m, sat_id, system,
        elevation_deg, cn0_dbhz`` (system: :data:`SYSTEM_CODES`; satellite ECEF at transmit time;
        var_m2 / elevation_deg / cn0_dbhz NaN where the file does not give them).
    odom : DataFrame ``t_s, speed_mps, yaw_rate_radps`` (yaw rate about the vehicle up axis,
        counter-clockwise positive), or None.
    truth : DataFrame ``t_s, x_m, y_m, z_m`` (ECEF), or None.
    """

    name: str
    pr: pd.DataFrame
    odom: pd.DataFrame | None
    truth: pd.DataFrame | None
    source: str

    @property
    def epochs_s(self) -> np.ndarray:
        return np.unique(self.pr.t_s.to_numpy())


PR_NAMES = (
    "t_s",
    "pseudorange_m",
    "var_m2",
    "sat_x_m",
    "sat_y_m",
    "sat_z_m",
    "sat_id",
    "system",
    "elevation_deg",
    "cn0_dbhz",
)
_PR_RANGES: dict[str, Range] = {
    "t_s": (-1e6, 1e9, "s"),
    "pseudorange_m": (1.0e7, 6.0e7, "m"),
    "var_m2": (1e-6, 1e10, "m²"),
    "sat_x_m": (-5e7, 5e7, "m"),
    "sat_y_m": (-5e7, 5e7, "m"),
    "sat_z_m": (-5e7, 5e7, "m"),
    "sat_id": (0, 1e4, ""),
    "system": (1, 32, ""),
    "elevation_deg": (-10.0, 90.0, "deg"),
    "cn0_dbhz": (0.0, 80.0, "dBHz"),
}
_ECEF_RANGES: dict[str, Range] = {"x_m": (-7e6, 7e6, "m"), "y_m": (-7e6, 7e6, "m"), "z_m": (-7e6, 7e6, "m")}


def _system_from_id(path: Path, sat_id: np.ndarray) -> np.ndarray:
    """System codes of an export without a system column: ids < 100 GPS, 300–399 / 600–699 GLONASS."""
    sys_ = np.where(
        sat_id < 100,
        1,
        np.where(((sat_id >= 300) & (sat_id < 400)) | ((sat_id >= 600) & (sat_id < 700)), 4, 0),
    )
    bad = np.flatnonzero(sys_ == 0)
    if bad.size:
        raise NavlabError(
            f"{path}: satellite id {sat_id[bad[0]]:.0f} (pseudorange row {bad[0] + 1}) cannot be assigned "
            "to a system without the system column (ids below 100 are read as GPS, 300–399 and 600–699 as "
            "GLONASS); give the column (1 GPS, 2 SBAS, 4 GLONASS, 8 Galileo, 16 QZSS, 32 BeiDou)"
        )
    return sys_


def _check_pr(path: Path, pr: np.ndarray) -> None:
    """Satellite ECEF positions at GNSS orbit radius; system codes among smartLoc's."""
    r = np.linalg.norm(pr[:, 3:6], axis=1)
    bad = np.flatnonzero((r < 1.9e7) | (r > 3.0e7))
    if bad.size:
        raise NavlabError(
            f"{path}: pseudorange row {bad[0] + 1} has a satellite {r[bad[0]]:.4g} m from "
            "the Earth's centre (expected 2.0e7–2.6e7); the satellite position must be ECEF metres"
        )
    codes = pr[:, 7]
    bad = np.flatnonzero(~np.isin(codes, list(SYSTEM_CODES)))
    if bad.size:
        raise NavlabError(
            f"{path}: pseudorange row {bad[0] + 1} has system code {codes[bad[0]]:g}, not one of "
            + ", ".join(f"{c} {n}" for c, n in SYSTEM_CODES.items())
        )


def _check_truth(path: Path, gt: np.ndarray) -> None:
    rg = np.linalg.norm(gt[:, 1:4], axis=1)
    bad = np.flatnonzero(np.abs(rg - 6.37e6) > 5e4)
    if bad.size:
        raise NavlabError(
            f"{path}: truth row {bad[0] + 1} is {rg[bad[0]]:.4g} m from the Earth's "
            "centre, not on the ground; give ECEF metres (or lat_deg, lon_deg, h_m)"
        )


def read_smartloc(f_in: Path, f_gt: Path | None = None, name: str | None = None) -> PseudorangeRecording:
    """Read a smartLoc ``*_Input.txt`` (and ``*_GT.txt``): the format of the smartLoc readme and
    its preprocessed variants.

    Accepted: ``pseudorange3`` lines (time, pseudorange, variance, satellite ECEF x y z, id,
    system, elevation, C/N0) and the same as ``range3`` lines (the RTKLIB-postprocessed smartLoc
    export); ``range3`` lines of the older web export without the system column (9 fields: the
    system is read from the id, :func:`_system_from_id`); any of smartLoc's system codes
    (:data:`SYSTEM_CODES`); ``odom3`` lines (optional: without them the scenario uses a
    constant-velocity model); a ``*_GT.txt`` with ``point3`` lines (optional: no truth, no errors).
    """
    lines = _read_text(f_in).splitlines()
    first = {ln.split(None, 1)[0] for ln in lines if ln.strip() and not ln.lstrip().startswith(("#", "%"))}
    kw = "pseudorange3" if "pseudorange3" in first else "range3" if "range3" in first else None
    if kw is None:
        raise NavlabError(
            f"{f_in}: no 'pseudorange3' or 'range3' lines found; this is not a smartLoc input file"
        )
    sample = next(ln.split() for ln in lines if ln.split()[:1] == [kw])
    if len(sample) - 1 >= 10:
        pr = _parse_rows(f_in, PR_NAMES, sep=None, keyword=kw, lines=lines, ranges=_PR_RANGES)
    else:
        names9 = tuple(n for n in PR_NAMES if n != "system")
        raw = _parse_rows(f_in, names9, sep=None, keyword=kw, lines=lines, ranges=_PR_RANGES)
        pr = np.column_stack([raw[:, :7], _system_from_id(f_in, raw[:, 6]), raw[:, 7:]])
    _check_pr(f_in, pr)
    _check_increasing(f_in, pr[:, 0], "pseudorange time")
    odom = None
    if "odom3" in first:
        od = _parse_rows(
            f_in,
            ("t_s", "vx", "vy", "vz", "wx", "wy", "wz"),
            sep=None,
            keyword="odom3",
            lines=lines,
            ranges={"vx": (-100.0, 100.0, "m/s"), "wz": (-10.0, 10.0, "rad/s")},
        )
        _check_increasing(f_in, od[:, 0], "odometry time")
        odom = pd.DataFrame({"t_s": od[:, 0], "speed_mps": od[:, 1], "yaw_rate_radps": od[:, 6]})
    truth = None
    if f_gt is not None:
        gt = _parse_rows(f_gt, ("t_s", "x_m", "y_m", "z_m"), sep=None, keyword="point3", ranges=_ECEF_RANGES)
        _check_truth(f_gt, gt)
        _check_increasing(f_gt, gt[:, 0])
        truth = pd.DataFrame(gt, columns=("t_s", "x_m", "y_m", "z_m"))
    pr_df = pd.DataFrame(pr, columns=PR_NAMES)
    pr_df["sat_id"] = pr_df.sat_id.astype(int)
    pr_df["system"] = pr_df.system.astype(int)
    nm = name or f_in.name.removesuffix(".txt")
    src = SMARTLOC_SOURCE if nm == SMARTLOC_DIR else f"{nm}: smartLoc-format files ({f_in.name})"
    return PseudorangeRecording(nm, pr_df, odom, truth, src)


def smartloc_berlin_pp(path: str | os.PathLike | None = None) -> PseudorangeRecording:
    """Load smartLoc Berlin Potsdamer Platz (``*_Input.txt`` and ``*_GT.txt``)."""
    d = _recording_dir(SMARTLOC_DIR, path)
    rec = read_smartloc(
        d / "Berlin_Potsdamer_Platz_Input.txt", d / "Berlin_Potsdamer_Platz_GT.txt", SMARTLOC_DIR
    )
    if rec.odom is None or rec.truth is None:
        raise NavlabError(f"{d}: the Berlin recording must hold odom3 lines and its GT file")
    return rec


def read_pseudorange_csv(folder: str | os.PathLike) -> PseudorangeRecording:
    """Load the generic pseudorange CSV format (docs/data.md, 'Your own pseudoranges').

    ``pseudoranges.csv`` (required): ``t_s, sat_id, system, pseudorange_m, sat_x_m, sat_y_m,
    sat_z_m`` and optionally ``var_m2, elevation_deg, cn0_dbhz`` — one row per satellite and
    epoch (rows of one epoch share ``t_s``); ``system`` is a smartLoc code (1 GPS, 2 SBAS,
    4 GLONASS, 8 Galileo, 16 QZSS, 32 BeiDou) or a RINEX letter (G, S, R, E, J, C); the satellite
    position is ECEF at TRANSMIT time (the model applies the Earth-rotation correction) and the
    pseudorange is corrected for the satellite clock and the atmosphere.
    ``odometry.csv`` (optional): ``t_s, speed_mps, yaw_rate_radps`` (counter-clockwise positive).
    ``truth.csv`` (optional): ``t_s`` and ``x_m, y_m, z_m`` (ECEF) or ``lat_deg, lon_deg, h_m``.
    """
    d = Path(folder).expanduser()
    f_pr = d / "pseudoranges.csv"
    lines = _read_text(f_pr).splitlines()
    hdr_i = next((i for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")), None)
    if hdr_i is not None:  # RINEX system letters -> smartLoc codes before the numeric parse
        header = [h.strip().strip('"') for h in lines[hdr_i].split(",")]
        if "system" in header:
            j = header.index("system")
            for i in range(hdr_i + 1, len(lines)):
                parts = lines[i].split(",")
                if len(parts) > j and parts[j].strip().upper() in SYSTEM_LETTERS:
                    parts[j] = str(SYSTEM_LETTERS[parts[j].strip().upper()])
                    lines[i] = ",".join(parts)
                elif len(parts) > j and parts[j].strip().isalpha():
                    raise NavlabError(
                        f"{f_pr}: line {i + 1}, column {j + 1} (system) is {parts[j].strip()[:10]!r}; give a "
                        "RINEX letter (G, R, E, C, J, S) or a smartLoc code (1 GPS, 2 SBAS, 4 GLONASS, "
                        "8 Galileo, 16 QZSS, 32 BeiDou)"
                    )
    req = ("t_s", "sat_id", "system", "pseudorange_m", "sat_x_m", "sat_y_m", "sat_z_m")
    opt = ("var_m2", "elevation_deg", "cn0_dbhz")
    prd = _read_header_csv(f_pr, req, opt, _PR_RANGES, lines=lines)
    for c in opt:
        if c not in prd.columns:
            prd[c] = np.nan
    prd = prd[list(PR_NAMES)]
    _check_pr(f_pr, prd.to_numpy())
    prd["sat_id"] = prd.sat_id.astype(int)
    prd["system"] = prd.system.astype(int)
    odom = None
    if (d / "odometry.csv").exists():
        odom = _read_header_csv(
            d / "odometry.csv",
            ("t_s", "speed_mps", "yaw_rate_radps"),
            (),
            {"speed_mps": (-100.0, 100.0, "m/s"), "yaw_rate_radps": (-10.0, 10.0, "rad/s")},
        )
    truth = None
    f_gt = d / "truth.csv"
    if f_gt.exists():
        header = next(
            (ln for ln in _read_text(f_gt).splitlines() if ln.strip() and not ln.lstrip().startswith("#")), ""
        )
        if "x_m" in [h.strip().strip('"') for h in header.split(",")]:
            truth = _read_header_csv(f_gt, ("t_s", "x_m", "y_m", "z_m"), (), _ECEF_RANGES)
        else:
            from navlab.ins.earth import geodetic_to_ecef

            g = _read_header_csv(f_gt, ("t_s", "lat_deg", "lon_deg", "h_m"), (), _POS_RANGES)
            xyz = geodetic_to_ecef(
                np.radians(g.lat_deg.to_numpy()), np.radians(g.lon_deg.to_numpy()), g.h_m.to_numpy()
            )
            truth = pd.DataFrame({"t_s": g.t_s, "x_m": xyz[:, 0], "y_m": xyz[:, 1], "z_m": xyz[:, 2]})
        _check_truth(f_gt, truth.to_numpy())
    return PseudorangeRecording(
        d.name, prd.reset_index(drop=True), odom, truth, f"{d.name}: generic pseudorange CSV"
    )


def load_pseudoranges(data_dir: str | os.PathLike | None = None) -> PseudorangeRecording:
    """The Berlin recording (default), a generic pseudorange CSV folder, or one smartLoc sequence.

    ``data_dir`` may be the data root, the Berlin folder, a folder with ``pseudoranges.csv``
    (:func:`read_pseudorange_csv`) or a folder holding one smartLoc sequence (``*_Input.txt`` and
    optionally ``*_GT.txt``, :func:`read_smartloc`).
    """
    if data_dir:
        d = Path(data_dir).expanduser()
        if (d / "pseudoranges.csv").exists():
            return read_pseudorange_csv(d)
        if not (d / SMARTLOC_DIR).is_dir() and d.name != SMARTLOC_DIR and d.is_dir():
            inputs = sorted(d.glob("*_Input.txt"))
            if len(inputs) > 1:
                raise NavlabError(
                    f"{d}: {len(inputs)} smartLoc sequences ({', '.join(p.name for p in inputs)}); put one "
                    "sequence (its *_Input.txt and *_GT.txt) per folder"
                )
            if inputs:
                f_in = inputs[0]
                stem = f_in.name.removesuffix("_Input.txt")
                f_gt = d / f"{stem}_GT.txt"
                return read_smartloc(f_in, f_gt if f_gt.exists() else None, stem)
            raise NavlabError(
                f"{d}: neither pseudoranges.csv (generic format) nor a smartLoc *_Input.txt in this folder"
            )
    return smartloc_berlin_pp(data_dir)
