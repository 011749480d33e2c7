"""Loaders of the real recordings (../shared/data) and the generic CSV format."""

import shutil

import numpy as np
import pytest

from navlab.data import data_root, load_generic, rtkx_drive_0708, smartloc_berlin_pp
from navlab.data.loaders import RTKX_DIR, SMARTLOC_DIR, load_drive
from navlab.errors import NavlabError

ROOT = data_root()
needs_rtkx = pytest.mark.skipif(
    not (ROOT / RTKX_DIR).is_dir(), reason=f"real data not found: {ROOT / RTKX_DIR} (set NAVLAB_DATA)"
)
needs_smartloc = pytest.mark.skipif(
    not (ROOT / SMARTLOC_DIR).is_dir(),
    reason=f"real data not found: {ROOT / SMARTLOC_DIR} (set NAVLAB_DATA)",
)


@pytest.fixture(scope="module")
def rtkx():
    return rtkx_drive_0708()


@pytest.fixture(scope="module")
def smartloc():
    return smartloc_berlin_pp()


@needs_rtkx
def test_rtkx_counts_spans_units(rtkx):
    # data README: 54,860 IMU rows at ≈100 Hz, 2197 epochs at 4 Hz of which 2189 fixed, 549 s
    assert len(rtkx.imu) == 54860
    assert len(rtkx.gnss) == 2197
    assert len(rtkx.truth) == 2189
    assert rtkx.duration_s == pytest.approx(549.0, abs=1.0)
    assert np.median(np.diff(rtkx.imu.t_s)) == pytest.approx(0.01, abs=5e-4)
    assert np.median(np.diff(rtkx.gnss.t_s)) == pytest.approx(0.25, abs=1e-6)
    assert 0.01 < rtkx.imu.repeated.mean() < 0.03  # ≈2 % repeated readings
    # static start: |f| ≈ g in m/s², gyro small in rad/s
    f = rtkx.imu[["f_x_mps2", "f_y_mps2", "f_z_mps2"]].to_numpy()[:2000]
    assert np.linalg.norm(f.mean(axis=0)) == pytest.approx(9.80, abs=0.15)
    w = rtkx.imu[["w_x_radps", "w_y_radps", "w_z_radps"]].to_numpy()[:2000]
    assert np.abs(w.mean(axis=0)).max() < 0.01
    assert rtkx.gnss.lat_deg.mean() == pytest.approx(40.10, abs=0.02)
    assert rtkx.gnss.lon_deg.mean() == pytest.approx(-105.15, abs=0.02)
    assert rtkx.gnss.h_m.mean() == pytest.approx(1600, abs=30)
    assert rtkx.gnss[["vn_mps", "ve_mps"]].abs().max().max() < 20


@needs_smartloc
def test_smartloc_counts_spans_units(smartloc):
    assert len(smartloc.pr) == 20038
    assert len(smartloc.odom) == 1372
    assert len(smartloc.truth) == 1372
    assert len(smartloc.epochs_s) == 1372
    assert smartloc.pr.t_s.max() - smartloc.pr.t_s.min() == pytest.approx(283, abs=1.0)
    assert set(smartloc.pr.system.unique()) == {1, 4}
    assert smartloc.pr.groupby("t_s").size().median() == 15
    assert smartloc.odom.speed_mps.max() < 30


def _copy(src_dir, tmp_path, name):
    dst = tmp_path / name
    shutil.copytree(src_dir / name, dst)
    for p in dst.iterdir():
        p.chmod(0o644)
    return dst


def _corrupt_line(path, lineno, new):
    lines = path.read_text().splitlines()
    lines[lineno - 1] = new
    path.write_text("\n".join(lines) + "\n")


@needs_rtkx
@pytest.mark.parametrize(
    ("line", "content", "match"),
    [
        (100, "0.1,0.0,nan,0,0,0,262896", r"line 100, column 3 \(az_g\).*NaN"),
        (7, "0.1,0.0,1.0,0,0", r"line 7 has 5 column"),
        (50, "0.1,0.0,1e9,0,0,0,262396", r"line 50, column 3 .* outside the plausible range"),
        (20, "0.1,abc,1.0,0,0,0,262096", r"line 20, column 2 \(ay_g\) is 'abc', not a number"),
    ],
)
def test_rtkx_corrupted_imu_rejected(tmp_path, line, content, match):
    d = _copy(ROOT, tmp_path, RTKX_DIR)
    _corrupt_line(d / "imu_1934.csv", line, content)
    with pytest.raises(NavlabError, match=match) as ei:
        rtkx_drive_0708(tmp_path)
    assert "imu_1934.csv" in str(ei.value)


@needs_rtkx
def test_rtkx_empty_missing_and_bad_pos(tmp_path):
    d = _copy(ROOT, tmp_path, RTKX_DIR)
    (d / "imu_1934.csv").write_text("")
    with pytest.raises(NavlabError, match="empty"):
        rtkx_drive_0708(tmp_path)
    shutil.copy(ROOT / RTKX_DIR / "imu_1934.csv", d / "imu_1934.csv")
    (d / "imu_1934.csv.tag").unlink()
    with pytest.raises(NavlabError, match="tag"):
        rtkx_drive_0708(tmp_path)
    shutil.copy(ROOT / RTKX_DIR / "imu_1934.csv.tag", d / "imu_1934.csv.tag")
    _corrupt_line(d / "gnss_1934_sf.pos", 30, "2025/07/08 19:34:25.499 40.1 -105.1 inf 1 20")
    with pytest.raises(NavlabError, match=r"gnss_1934_sf.pos: line 30"):
        rtkx_drive_0708(tmp_path)


def test_missing_data_dir_message(tmp_path):
    with pytest.raises(NavlabError, match="NAVLAB_DATA"):
        rtkx_drive_0708(tmp_path / "nowhere")


def test_env_var_overrides_root(tmp_path, monkeypatch):
    monkeypatch.setenv("NAVLAB_DATA", str(tmp_path))
    assert data_root() == tmp_path
    assert data_root(tmp_path / "x") == tmp_path / "x"


@needs_smartloc
def test_smartloc_corrupted_rejected(tmp_path):
    d = _copy(ROOT, tmp_path, SMARTLOC_DIR)
    f = d / "Berlin_Potsdamer_Platz_Input.txt"
    lines = f.read_text().splitlines()
    i = next(i for i, ln in enumerate(lines) if ln.startswith("pseudorange3"))
    parts = lines[i].split()
    parts[3] = "NaN"
    _corrupt_line(f, i + 1, " ".join(parts))
    with pytest.raises(NavlabError, match=rf"Input.txt: line {i + 1}, column 3 \(var_m2\)"):
        smartloc_berlin_pp(tmp_path)
    shutil.copy(ROOT / SMARTLOC_DIR / f.name, f)
    parts = lines[i].split()
    parts[2] = "19949.087"  # km instead of m
    _corrupt_line(f, i + 1, " ".join(parts))
    with pytest.raises(NavlabError, match="pseudorange_m"):
        smartloc_berlin_pp(tmp_path)
    (d / "Berlin_Potsdamer_Platz_GT.txt").write_text("# nothing\n")
    shutil.copy(ROOT / SMARTLOC_DIR / f.name, f)
    with pytest.raises(NavlabError, match="no 'point3' lines"):
        smartloc_berlin_pp(tmp_path)


def _write_generic(tmp_path, n=300, fz=9.81):
    t = np.arange(n) * 0.01
    imu = "t_s,f_x_mps2,f_y_mps2,f_z_mps2,w_x_radps,w_y_radps,w_z_radps\n" + "\n".join(
        f"{ti:.2f},0.01,0.02,{fz},0.001,0.0,0.0" for ti in t
    )
    (tmp_path / "imu.csv").write_text(imu + "\n")
    g = "t_s,lat_deg,lon_deg,h_m,sigma_n_m\n" + "\n".join(
        f"{ti:.1f},40.0,-105.0,1600.0,2.0" for ti in np.arange(0, n * 0.01, 1.0)
    )
    (tmp_path / "gnss.csv").write_text(g + "\n")


def test_generic_roundtrip_and_errors(tmp_path):
    _write_generic(tmp_path)
    rec = load_drive(tmp_path)
    assert len(rec.imu) == 300 and len(rec.gnss) == 3
    assert rec.gnss.sigma_n_m.iloc[0] == 2.0 and np.isnan(rec.gnss.vn_mps.iloc[0])
    assert rec.truth is None
    _write_generic(tmp_path, fz=1.0)  # in g
    with pytest.raises(NavlabError, match=r"m/s²"):
        load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv")
    _write_generic(tmp_path)
    (tmp_path / "gnss.csv").write_text("t_s,lat_deg,h_m\n0,40,1600\n")
    with pytest.raises(NavlabError, match=r"gnss.csv: line 1 \(header\) lacks column\(s\) lon_deg"):
        load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv")
    (tmp_path / "gnss.csv").write_text("t_s,lat_deg,lon_deg,h_m\n0,40,-105,1600\n1,95,-105,1600\n")
    with pytest.raises(NavlabError, match=r"line 3, column 2 \(lat_deg\) = 95"):
        load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv")


# ------------------------------------------------------------------ hardening, round three (issue 22)


def _rows(path):
    lines = path.read_text().splitlines()
    return lines[:1], lines[1:]


@pytest.mark.parametrize("which", ["imu", "gnss"])
def test_every_row_written_twice_is_refused_with_its_rows(tmp_path, which):
    """Issue 22 items 1-2: equal time stamps gave ZeroDivisionError / 'Maximum allowed size exceeded'."""
    _write_generic(tmp_path)
    f = tmp_path / f"{which}.csv"
    head, body = _rows(f)
    f.write_text("\n".join(head + [r for row in body for r in (row, row)]) + "\n")
    n = 2 * len(body)
    with pytest.raises(
        NavlabError, match=rf"{which}.csv: data rows 1 and 2 have the same time .*{n // 2} of {n} rows repeat"
    ) as e:
        load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv")
    assert "delete rows written twice" in str(e.value)


def test_one_repeated_time_stamp_a_leap_second_is_refused(tmp_path):
    """Issue 22 item 3: one repeated GNSS time (a leap second) ended in 'SVD did not converge'."""
    _write_generic(tmp_path, n=600)
    f = tmp_path / "gnss.csv"
    head, body = _rows(f)
    body[3] = body[2]
    f.write_text("\n".join(head + body) + "\n")
    with pytest.raises(
        NavlabError, match=r"gnss.csv: data rows 3 and 4 have the same time \(2; one row repeats"
    ):
        load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv")


@pytest.mark.parametrize(
    ("unit", "per_s"), [("milliseconds", 1e3), ("microseconds", 1e6), ("nanoseconds", 1e9)]
)
def test_times_not_in_seconds_name_the_unit_they_seem_to_be_in(tmp_path, unit, per_s):
    """Issue 22 item 5: nanoseconds were refused with a misleading cause (too few IMU samples)."""
    _write_generic(tmp_path, n=600)
    for name in ("imu.csv", "gnss.csv"):
        f = tmp_path / name
        head, body = _rows(f)
        body = [f"{float(r.split(',', 1)[0]) * per_s:.0f},{r.split(',', 1)[1]}" for r in body]
        f.write_text("\n".join(head + body) + "\n")
    with pytest.raises(NavlabError, match=rf"t_s must be seconds, but it looks like {unit}") as e:
        load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv")
    assert f"an IMU at 100 Hz, fixes at 1 Hz); divide t_s by {per_s:.0e}" in str(e.value)


@pytest.mark.parametrize(("name", "what"), [("imu.csv", "IMU samples"), ("gnss.csv", "GNSS fixes")])
def test_one_file_in_milliseconds_is_named(tmp_path, name, what):
    """Only the IMU in ms was refused as 'only 1 IMU samples before the vehicle moves (at 4.0 s)'."""
    _write_generic(tmp_path, n=600)
    f = tmp_path / name
    head, body = _rows(f)
    body = [f"{float(r.split(',', 1)[0]) * 1e3:.0f},{r.split(',', 1)[1]}" for r in body]
    f.write_text("\n".join(head + body) + "\n")
    with pytest.raises(
        NavlabError, match=rf"t_s must be seconds in every file, but the {what} are .* milliseconds"
    ):
        load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv")


def test_a_truth_in_another_unit_is_named(tmp_path):
    _write_generic(tmp_path, n=600)
    (tmp_path / "truth.csv").write_text(
        "t_s,lat_deg,lon_deg,h_m\n" + "".join(f"{t * 1e9:.0f},40.0,-105.0,1600.0\n" for t in range(1, 7))
    )
    with pytest.raises(NavlabError, match=r"do not overlap in time \(the truth's t_s looks like nanoseconds"):
        load_drive(tmp_path)


def test_a_csv_beyond_the_memory_budget_is_refused_before_it_is_read(tmp_path, monkeypatch):
    """Issue 22 item 6: 10 million IMU rows ran for minutes above 2.3 GB with no estimate."""
    _write_generic(tmp_path, n=3000)
    monkeypatch.setenv("NAVLAB_MEMORY_BUDGET", "100kB")
    import navlab.data.loaders as L

    def unread(*a, **k):
        raise AssertionError("read although refused")

    monkeypatch.setattr(L, "_read_text", unread)
    with pytest.raises(
        NavlabError,
        match=r"imu.csv: .*about 3,0[0-9][0-9] rows: reading it would hold about .* more than the "
        r"memory budget of 100 kB \(NAVLAB_MEMORY_BUDGET=100kB\); cut the recording",
    ):
        load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv")
    monkeypatch.undo()
    assert len(load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv").imu) == 3000
