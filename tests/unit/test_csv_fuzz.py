"""Property-based tests of the generic CSV readers (issue 22): whatever a user's files hold —
another encoding, repeated or backward times, another time unit, NaN/Inf, blank cells, no rows,
too many rows for the memory budget — reading them and preparing the drive either works or
raises navlab's own error (:class:`navlab.errors.NavlabError`), never anything else.

Deterministic (``derandomize``) and small, so CI runs the same examples every time.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from navlab.data import loaders as L
from navlab.data.checks import check_drive
from navlab.errors import NavlabError
from navlab.ins.lc import prepare_drive

SETTINGS = settings(
    max_examples=60,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
BAD_CELLS = ("nan", "inf", "-inf", "1e308", "-1e308", "", " ", "abc", "1,5", '"1.0"', "NA", "0x10", "1e-320")
ENCODINGS = ("utf-8-sig", "utf-16", "utf-32", "cp1252", "binary")
ENDINGS = ("\n", "\r\n", "\r")


FAULTS = (
    "none",
    "encoding",
    "cell",
    "twice",
    "one-repeat",
    "backwards",
    "unit",
    "jitter",
    "empty",
    "header-only",
    "few-rows",
    "sigma-0",
    "line-endings",
)
IMU_H = ("t_s", "f_x_mps2", "f_y_mps2", "f_z_mps2", "w_x_radps", "w_y_radps", "w_z_radps")
POS_H = ("t_s", "lat_deg", "lon_deg", "h_m")


def retime(draw, t: np.ndarray, fault: str) -> np.ndarray:
    """Times with ``fault``: every row twice, one repeated, a step back, another unit, jitter."""
    t, n = t.copy(), len(t)
    if n < 2:
        return t
    if fault == "twice":
        t = np.repeat(t, 2)[:n]
    elif fault == "one-repeat":
        i = draw(st.integers(1, n - 1))
        t[i] = t[i - 1]
    elif fault == "backwards":
        i = draw(st.integers(1, n - 1))
        t[i] = t[i - 1] - draw(st.floats(0.0, 5.0))
    elif fault == "unit":
        t = t * draw(st.sampled_from([1e3, 1e6, 1e9]))
    elif fault == "jitter":
        t = t + draw(st.floats(0.0, 0.004)) * np.sin(np.arange(n))
    return t


def csv_bytes(draw, header, rows: np.ndarray, fault: str) -> bytes:
    """The file of ``rows`` under ``header``, with ``fault`` (a bad cell, an encoding, …)."""
    lines = [",".join(header)] + [",".join(repr(float(v)) for v in r) for r in rows]
    if fault == "cell":
        i = draw(st.integers(1, len(lines) - 1))
        cells = lines[i].split(",")
        cells[draw(st.integers(0, len(cells) - 1))] = draw(st.sampled_from(BAD_CELLS))
        lines[i] = ",".join(cells)
    elif fault == "empty":
        lines = []
    elif fault == "header-only":
        lines = lines[:1]
    elif fault == "few-rows":
        lines = lines[: draw(st.integers(2, 4))]
    if draw(st.booleans()):
        lines.insert(0, "# a comment line: µ, °C")
    end = draw(st.sampled_from(ENDINGS)) if fault == "line-endings" else "\n"
    text = end.join(lines) + ("\n" if lines else "")
    if fault != "encoding":
        return text.encode()
    enc = draw(st.sampled_from(ENCODINGS))
    if enc == "binary":
        return draw(st.binary(min_size=1, max_size=200)) + text.encode()
    return text.encode(enc, errors="replace")


@st.composite
def drive(draw) -> dict[str, bytes]:
    """imu.csv, gnss.csv (and maybe truth.csv) of a short drive with one fault in one file."""
    fault = draw(st.sampled_from(FAULTS))
    where = draw(st.sampled_from(["imu.csv", "gnss.csv", "truth.csv"]))
    seconds = draw(st.sampled_from([12, 30]))
    speed = draw(st.sampled_from([0.0, 8.0]))
    start_moving = draw(st.booleans())
    n = 100 * seconds
    t = np.arange(n) * 0.01
    moving = (t > (0.0 if start_moving else 5.0)).astype(float)
    f = np.tile([0.05, 0.1, 9.81], (n, 1))
    f[:, 1] += 0.3 * np.sin(0.7 * t) * moving
    w = np.zeros((n, 3))
    w[:, 2] = draw(st.sampled_from([0.0, 0.05])) * np.sin(0.5 * t) * moving
    tg = np.arange(0.0, seconds, 1.0)
    north = speed * np.maximum(tg - (0.0 if start_moving else 5.0), 0.0)
    lat = 40.0 + north / 111_000.0
    gcols, gdata = list(POS_H), [tg, lat, np.full(len(tg), -105.0), np.full(len(tg), 1600.0)]
    if draw(st.booleans()) or (fault == "sigma-0" and where == "gnss.csv"):
        sig = 0.0 if fault == "sigma-0" else 2.0
        gcols += ["sigma_n_m", "sigma_e_m", "sigma_u_m"]
        gdata += [np.full(len(tg), sig)] * 3
    if draw(st.booleans()):
        gcols += ["vn_mps", "ve_mps", "vu_mps"]
        gdata += [speed * (tg >= (0.0 if start_moving else 5.0)), np.zeros(len(tg)), np.zeros(len(tg))]
    truth = draw(st.booleans()) or where == "truth.csv"
    out = {}
    for name, header, data in (
        ("imu.csv", IMU_H, [t, *f.T, *w.T]),
        ("gnss.csv", gcols, gdata),
        *([("truth.csv", POS_H, gdata[:4])] if truth else []),
    ):
        mine = fault if name == where else "none"
        data = [retime(draw, data[0], mine), *data[1:]]
        out[name] = csv_bytes(draw, header, np.column_stack(data), mine)
    return out


@SETTINGS
@given(files=drive(), budget=st.sampled_from([None, None, None, "20kB"]))
def test_a_drive_of_any_content_reads_and_prepares_or_says_what_is_wrong(tmp_path_factory, files, budget):
    d = tmp_path_factory.mktemp("drive")
    for name, raw in files.items():
        (d / name).write_bytes(raw)
    with pytest.MonkeyPatch.context() as mp:
        if budget is None:
            mp.delenv("NAVLAB_MEMORY_BUDGET", raising=False)
        else:
            mp.setenv("NAVLAB_MEMORY_BUDGET", budget)
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            try:
                rec = L.load_drive(d)
                setup = prepare_drive(rec, recorded=True)
                findings = check_drive(rec, setup)
            except NavlabError:
                return
    assert np.isfinite(setup.t).all() and np.all(np.diff(setup.t) > 0)
    assert all(f.level in ("note", "warning") for f in findings)


@st.composite
def pseudoranges(draw) -> dict[str, bytes]:
    """pseudoranges.csv (and maybe odometry.csv, truth.csv) of a few epochs with one fault."""
    fault = draw(st.sampled_from(FAULTS))
    where = draw(st.sampled_from(["pseudoranges.csv", "odometry.csv", "truth.csv"]))
    epochs, sats = draw(st.integers(1, 6)), draw(st.integers(1, 6))
    t = np.repeat(np.arange(epochs, dtype=float), sats)
    sat = np.tile(np.arange(1, sats + 1, dtype=float), epochs)
    ang = sat * 0.9
    xyz = 2.6e7 * np.column_stack([np.cos(ang), np.sin(ang), 0.3 * np.ones_like(ang)]) / 1.044
    rows = np.column_stack([t, sat, np.ones_like(t), 2.2e7 + 10 * t, xyz])
    head = ("t_s", "sat_id", "system", "pseudorange_m", "sat_x_m", "sat_y_m", "sat_z_m")
    mine = lambda name: fault if name == where else "none"  # noqa: E731
    out = {"pseudoranges.csv": csv_bytes(draw, head, rows, mine("pseudoranges.csv"))}
    to = np.arange(epochs, dtype=float) + 0.5
    if draw(st.booleans()) or where == "odometry.csv":
        odo = np.column_stack(
            [retime(draw, to, mine("odometry.csv")), np.full(epochs, 5.0), np.zeros(epochs)]
        )
        out["odometry.csv"] = csv_bytes(
            draw, ("t_s", "speed_mps", "yaw_rate_radps"), odo, mine("odometry.csv")
        )
    if draw(st.booleans()) or where == "truth.csv":
        g = np.column_stack([retime(draw, to, mine("truth.csv")), np.full((epochs, 3), [52.5, 13.4, 40.0])])
        out["truth.csv"] = csv_bytes(draw, POS_H, g, mine("truth.csv"))
    return out


@SETTINGS
@given(files=pseudoranges())
def test_a_pseudorange_folder_of_any_content_reads_or_says_what_is_wrong(tmp_path_factory, files):
    d = tmp_path_factory.mktemp("pr")
    for name, raw in files.items():
        (d / name).write_bytes(raw)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        try:
            rec = L.load_pseudoranges(d)
        except NavlabError:
            return
    assert len(rec.pr) > 0 and np.isfinite(rec.pr[["t_s", "pseudorange_m"]].to_numpy()).all()


@st.composite
def plain_body(draw) -> tuple[str, int]:
    """Rows of plain numbers (and now and then a cell the line parser must judge)."""
    ncol = draw(st.integers(1, 5))
    nums = st.one_of(
        st.floats(allow_nan=False, allow_infinity=False, width=64).map(repr),
        st.integers(-(10**20), 10**20).map(str),
        st.floats(-1e6, 1e6).map(lambda v: f"{v:.3f}"),
        st.floats(-1e6, 1e6).map(lambda v: f"{v:.6e}"),
        st.sampled_from((*BAD_CELLS, "+1", "-0", ".5", "5.", "1_000", " 2", "3 ", "1e5", "1E+05")),
    )
    rows = draw(st.lists(st.lists(nums, min_size=ncol, max_size=ncol + 1), min_size=0, max_size=30))
    blank = draw(st.booleans())
    lines = [",".join(r) for r in rows] + ([""] if blank else [])
    return draw(st.sampled_from(["\n", "\r\n"])).join(lines) + "\n", ncol


@pytest.mark.slow
@settings(max_examples=300, deadline=None, derandomize=True)
@given(case=plain_body())
def test_the_fast_parse_gives_the_line_parsers_numbers_or_leaves_it_to_it(case):
    """The C-speed path of the header CSVs (:func:`navlab.data.loaders._fast_rows`) accepts a
    file only when the line parser would, with exactly its numbers."""
    body, ncol = case
    names = tuple(f"c{j}" for j in range(ncol))
    ranges = {"c0": (-1e12, 1e12, "")}
    fast = L._fast_rows(body, names, ranges)
    try:
        slow = L._parse_rows(
            Path("x.csv"), names, lines=body.splitlines(), ranges=ranges, skip=lambda s: False
        )
    except NavlabError:
        assert fast is None
        return
    if fast is not None:
        assert fast.shape == slow.shape
        assert all(
            math.copysign(1, a) == math.copysign(1, b)
            for a, b in zip(fast.ravel(), slow.ravel(), strict=True)
        )
        np.testing.assert_array_equal(fast, slow)
