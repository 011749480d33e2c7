"""Own recordings (scenario own-drive): time gaps, in-motion starts, the data as recorded, receiver
σ, mounting, lever arm, GNSS time offset, and the checks before and after a run.

The real-data tests cut short slices of rtkx_drive_0708 with examples/convert_drive0708.py (the
worked conversion of the README), so the example is tested too; they skip without the data.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from navlab.cli import main
from navlab.data import data_root
from navlab.data.checks import TRUST_FACTOR, Finding, heading_change_slope, time_offset_hint, trust_check
from navlab.data.loaders import RTKX_DIR
from navlab.experiment import ExperimentSpec, plan, run_experiment
from navlab.ins.lc import bridge_gaps, gap_Qc, gap_time_per_block

ROOT = Path(__file__).resolve().parents[2]
needs_rtkx = pytest.mark.skipif(
    not (data_root() / RTKX_DIR).is_dir(), reason=f"real data not found: {data_root() / RTKX_DIR}"
)
MOUNT = {"mount_roll_deg": -6.8, "mount_yaw_deg": 95.4}  # rtkx IMU in the vehicle frame


def _convert(out: Path, *args: str) -> None:
    sys.path.insert(0, str(ROOT / "examples"))
    try:
        import convert_drive0708
    finally:
        sys.path.pop(0)
    assert convert_drive0708.main(["--out", str(out), *args]) == 0


def _run(folder: Path, filters=("kf",), mount=MOUNT, **params):
    spec = ExperimentSpec(
        scenario="own-drive",
        filters=tuple(filters),
        runs=1,
        scenario_params={"data_dir": str(folder), **mount, **params},
    )
    return run_experiment(spec)


def _metric(res, key, metric):
    df = res.metrics()
    return float(df[(df["filter"] == key) & (df.metric == metric)].value.iloc[0])


@pytest.fixture(scope="module")
def moving(tmp_path_factory):
    """90 s of the drive cut where the car first exceeds 5 m/s, fixes σ = 3 m with receiver σ."""
    if not (data_root() / RTKX_DIR).is_dir():
        pytest.skip("real data not found")
    d = tmp_path_factory.mktemp("moving")
    _convert(d, "--seconds", "90")
    return d


# ------------------------------------------------------------------ gaps (issue 12, item 5)


def test_bridge_gaps_interpolates_and_reports():
    t = np.r_[np.arange(0, 1, 0.01), np.arange(3.0, 4, 0.01)]
    f = np.c_[t, 2 * t, 3 * t]
    tt, ff, _ww, gaps = bridge_gaps(t, f, f.copy())
    assert gaps == [(pytest.approx(0.99), pytest.approx(2.01))]
    assert np.max(np.diff(tt)) < 0.011 and np.allclose(ff[:, 1], 2 * tt)
    per = gap_time_per_block(np.array([0.0, 1.0, 2.0, 3.0, 4.0]), gaps)
    np.testing.assert_allclose(per, [0, 0.01, 1.0, 1.0, 0], atol=1e-9)
    assert np.all(np.diag(gap_Qc(0.5))[:6] > 0) and np.all(np.diag(gap_Qc(0.5))[6:] == 0)
    assert bridge_gaps(t[:100], f[:100], f[:100])[3] == []


@needs_rtkx
def test_imu_and_gnss_gaps_give_a_note_not_a_crash(tmp_path, capsys):
    """Before: IndexError 'index 0 is out of bounds' for an imu.csv with a 2 s gap."""
    _convert(tmp_path, "--seconds", "60")
    imu = pd.read_csv(tmp_path / "imu.csv", comment="#")
    t0 = imu.t_s.iloc[0]
    imu[~imu.t_s.between(t0 + 30.0, t0 + 32.0)].to_csv(tmp_path / "imu.csv", index=False)
    gnss = pd.read_csv(tmp_path / "gnss.csv", comment="#")
    gnss[~gnss.t_s.between(t0 + 40.0, t0 + 45.0)].to_csv(tmp_path / "gnss.csv", index=False)
    res = _run(tmp_path)
    notes = " ".join(res.data.extras["notes"])
    assert "IMU: 1 time gap(s) bridged" in notes and "longest 2.0" in notes
    assert "GNSS: 5 epoch(s) without a fix" in notes
    assert _metric(res, "kf", "diverged") == 0 and np.isfinite(_metric(res, "kf", "rmse_pos"))
    assert _metric(res, "kf", "rmse_pos") < 5.0
    rc = main(
        ["run", "--scenario", "own-drive", "--filters", "kf", "--set", f"scenario.data_dir={tmp_path}"]
        + [f"--set=scenario.{k}={v}" for k, v in MOUNT.items()]
    )
    err = capsys.readouterr().err
    assert rc == 0 and "time gap(s) bridged" in err and "Traceback" not in err


# ------------------------------------------------------------------ starts in motion, data as recorded


@needs_rtkx
def test_a_drive_cut_at_speed_starts_in_motion_and_beats_its_gnss(moving):
    res = _run(moving, eval_from_s=0.0)
    d = res.data
    assert d.extras["start"] == "moving"
    assert any("GNSS: the recorded fixes as recorded" in n for n in d.extras["notes"])
    t_cut = d.extras["t_abs_s"][0]
    late = _run(moving, eval_from_s=float(t_cut) + 30.0)
    raw = next(f for f in trust_check(late) if f.level == "note").text
    kf = _metric(late, "kf", "rmse_pos")
    gnss = float(raw.split("fixes ")[1].split(" m")[0])
    assert kf < 0.6 * gnss  # 1 Hz fixes of 3 m per axis: ≈ 5.2 m 3-D
    assert not any(f.level == "warning" for f in trust_check(late))


@needs_rtkx
def test_recorded_fixes_are_fed_unchanged_and_receiver_sigmas_set_R(moving):
    res = _run(moving)
    d = res.data
    assert not d.outlier_mask.any()  # no synthetic outliers by default for own data
    model = d.model
    assert model.whitened and d.channel_units[:3] == ("σ", "σ", "σ")
    np.testing.assert_allclose(model.R0[:3, :3], np.eye(3))
    fixes = model.fixes(d.z)[0]
    g = pd.read_csv(moving / "gnss.csv", comment="#")
    ok = np.isfinite(fixes).all(axis=1)
    rec = model.setup.to_local(np.radians(g.lat_deg), np.radians(g.lon_deg), g.h_m.to_numpy())
    np.testing.assert_allclose(fixes[ok], rec[np.isin(g.t_s, d.extras["t_abs_s"][ok])], atol=1e-6)
    np.testing.assert_allclose(model.scale[:, :3][ok], 3.0)  # the file's sigma_* columns
    plain = _run(moving, use_receiver_sigmas=False, sigma_m=4.0)
    assert not plain.data.model.whitened and plain.data.channel_units[0] == "m"
    np.testing.assert_allclose(np.diag(plain.data.model.R0)[:3], 16.0)
    noisy = _run(moving, add_noise=True)
    assert not np.allclose(noisy.data.model.fixes(noisy.data.z)[0][1:], fixes[1:], equal_nan=True)
    assert any("synthetic noise" in n for n in noisy.data.extras["notes"])


@needs_rtkx
def test_gnss_rate_as_recorded_unless_resampled(tmp_path):
    _convert(tmp_path, "--seconds", "40", "--clean")  # 1 Hz fixes; the truth is 4 Hz
    (tmp_path / "gnss.csv").write_text((tmp_path / "truth.csv").read_text())  # a 4 Hz "receiver"
    d4 = _run(tmp_path, add_noise=True, use_receiver_sigmas=False).data
    assert np.median(np.diff(d4.t)) == pytest.approx(0.25)
    d1 = _run(tmp_path, add_noise=True, use_receiver_sigmas=False, gnss_rate_hz=1.0).data
    assert np.median(np.diff(d1.t)) == pytest.approx(1.0)


@needs_rtkx
def test_mounting_rotation_equals_rotating_the_columns(tmp_path, moving):
    from navlab.ins.align import body_to_vehicle

    imu = pd.read_csv(moving / "imu.csv", comment="#")
    C = body_to_vehicle(0.0, MOUNT["mount_yaw_deg"], MOUNT["mount_roll_deg"], nominal=np.eye(3))
    cols = [c for c in imu.columns if c != "t_s"]
    imu[cols[:3]] = imu[cols[:3]].to_numpy() @ C.T
    imu[cols[3:]] = imu[cols[3:]].to_numpy() @ C.T
    for f in ("gnss.csv", "truth.csv"):
        (tmp_path / f).write_text((moving / f).read_text())
    imu.to_csv(tmp_path / "imu.csv", index=False)
    spec = ExperimentSpec(
        scenario="own-drive",
        filters=("kf",),
        runs=1,
        scenario_params={"data_dir": str(tmp_path), "epochs": 40},
    )
    a = run_experiment(spec).runs["kf"].x[0, :, 6:9]
    b = _run(moving, epochs=40).runs["kf"].x[0, :, 6:9]
    np.testing.assert_allclose(a, b, atol=1e-6)


@needs_rtkx
def test_lever_arm_enters_the_measurement_and_its_jacobian(moving):
    res = _run(moving, epochs=20, lever_right_m=0.5, lever_forward_m=1.5, lever_up_m=1.0)
    m = res.data.model
    x = res.runs["kf"].x[0, 10][None].copy()
    x[:, 0:3] = 0.0  # the model linearises the attitude about the reference (a = 0)
    k = 10
    h0 = m.h(x, k)
    J = np.zeros((m.m, 15))
    for i in range(15):
        dx = np.zeros(15)
        dx[i] = 1e-6
        J[:, i] = (m.h(x + dx, k) - m.h(x - dx, k))[0] / 2e-6
    np.testing.assert_allclose(m.H(x, k)[0], J, atol=1e-5)
    no = _run(moving, epochs=20).data.model
    off = (h0 - no.h(x, k))[0, :3] * m.scale[k, :3]
    assert np.linalg.norm(off) == pytest.approx(np.linalg.norm([0.5, 1.5, 1.0]), rel=1e-6)


@pytest.fixture(scope="module")
def drive():
    """The bundled drive as tools/make_test_drives.py reads it (truth at any time, IMU in vehicle axes)."""
    if not (data_root() / RTKX_DIR).is_dir():
        pytest.skip("real data not found")
    sys.path.insert(0, str(ROOT / "tools"))
    try:
        import make_test_drives
    finally:
        sys.path.pop(0)
    return make_test_drives, make_test_drives.Drive()


@needs_rtkx
def test_an_in_motion_start_skips_a_first_fix_the_outlier_check_flags(tmp_path, drive):
    """Issue 24, recording (c) seeds 2 and 4: the run started AT an outlying first fix (73 m off,
    P0 of the receiver's σ), and the χ²-gated KF then rejected every good fix (diverged). It now
    starts from the first fix the pre-run check accepts, carried back with the GNSS velocity."""
    mk, d = drive
    rng = np.random.default_rng(3)
    t0 = d.first_above(5.0)
    mk.write(d, tmp_path, mk._times(rng, t0, t0 + 30, 0.07, 0.2), t0, t0 + 30, rng)
    spec = ExperimentSpec(scenario="own-drive", filters=("kf",), scenario_params={"data_dir": str(tmp_path)})
    t_start = plan(spec).scenario._setup()[1].t[0]  # the run's epoch 0 (a fix after the IMU's start)
    g = pd.read_csv(tmp_path / "gnss.csv", comment="#")
    i = int(np.argmin(np.abs(g.t_s.to_numpy() - t_start)))
    g.loc[i, "lat_deg"] += 60.0 / 111_000.0  # the run's first fix moved 60 m north
    g.to_csv(tmp_path / "gnss.csv", index=False)
    res = _run(tmp_path, filters=("chi2-kf",), mount={})
    dd = res.data
    assert dd.extras["raw_outliers"][0]  # the check flags it
    e0 = np.linalg.norm(dd.x0[0, 6:9] - dd.x_true[0, 0, 6:9])
    assert e0 < 3.0  # from the next fix, not 60 m off
    assert not res.runs["chi2-kf"].diverged.any() and _metric(res, "chi2-kf", "rmse_pos") < 3.0


@needs_rtkx
def test_the_raw_figure_says_after_it_which_fixes_it_leaves_out():
    """The note read "the raw GNSS fixes without their 34 outlying ones (all: 19.4 m) 5.17 m"."""
    spec = ExperimentSpec(scenario="drive0708", filters=("kf",), runs=1, epochs=60, contamination=0.2)
    note = next(f for f in trust_check(run_experiment(spec)) if f.level == "note").text
    assert re.search(
        r"the raw GNSS fixes [\d.]+ m \(\d+ outlying fixes left out; [\d.]+ m with them\); best ", note
    )


def _offset_finding(res):
    return next(f for f in res.data.extras["findings"] if "GNSS time offset" in f.text)


@needs_rtkx
def test_time_offset_hint_recovers_an_injected_offset_on_turns_and_is_silent_on_a_straight_road(
    tmp_path, drive
):
    mk, d = drive
    rng = np.random.default_rng(5)
    # turns: 80 s of town driving, the GNSS stamps written 0.3 s early
    w0 = d.window(80.0, straight=False)
    mk.write(d, tmp_path / "turn", mk._times(rng, w0, w0 + 80, 0.07, 0.2), w0, w0 + 80, rng, offset_s=0.3)
    res = _run(tmp_path / "turn", mount={})
    hint = _offset_finding(res)
    assert hint.level == "warning"
    value, pm = (float(x) for x in re.search(r"≈ ([-+\d.]+) ± ([\d.]+) s", hint.text).groups())
    # the drive's own IMU/RTK timing in this window, from the truth's course (no GNSS noise; the
    # RTK velocities stamped t hold the velocity of t − lag)
    m = (d.t >= w0) & (d.t <= w0 + 80)
    v_true = np.c_[d.v_ned[m][:, 1], d.v_ned[m][:, 0], d.v_ned[m][:, 2]]
    imu = d.imu.to_numpy()
    own = time_offset_hint(d.t[m] - d.v_lag, v_true, imu[:, 0], imu[:, 6])
    assert own.observable and abs(own.offset_s) < 0.05
    assert abs(value - (0.3 + own.offset_s)) <= pm + 2 * own.se_s
    assert 0 < pm <= 0.05
    # a straight road: no hint, and no warning among the checks
    s0 = d.window(40.0, straight=True)
    mk.write(d, tmp_path / "straight", mk._times(rng, s0, s0 + 40, 0.07, 0.2), s0, s0 + 40, rng)
    res = _run(tmp_path / "straight", mount={})
    hint = _offset_finding(res)
    assert hint.level == "note" and "not observable" in hint.text


@needs_rtkx
def test_upside_down_imu_is_named_before_the_run(tmp_path, moving):
    imu = pd.read_csv(moving / "imu.csv", comment="#")
    for c in ("f_y_mps2", "f_z_mps2", "w_y_radps", "w_z_radps"):  # an FRD-style z-down IMU
        imu[c] = -imu[c]
    imu.to_csv(tmp_path / "imu.csv", index=False)
    for f in ("gnss.csv", "truth.csv"):
        (tmp_path / f).write_text((moving / f).read_text())
    res = _run(tmp_path, epochs=30)
    text = " ".join(f.text for f in res.data.extras["findings"] if f.level == "warning")
    assert "z axis points DOWN" in text


def test_gyro_slope_tells_units_and_sign():
    t_g = np.arange(0, 120, 1.0)
    course = 0.5 * np.sin(t_g / 10.0)  # turning left and right, clockwise from north
    v = 10 * np.c_[np.sin(course), np.cos(course), 0 * t_g]
    t_i = np.arange(0, 120, 0.01)
    w_true = -np.interp(t_i, t_g, np.gradient(course, t_g))  # counter-clockwise
    for scale, want in ((1.0, 1.0), (np.degrees(1.0), 57.3), (-1.0, -1.0)):
        slope, r, n = heading_change_slope(t_g, v, t_i, scale * w_true, 2.0)
        assert slope == pytest.approx(want, rel=0.05) and abs(r) > 0.9 and n > 10
    est = time_offset_hint(t_g + 0.3, v, t_i, w_true)
    assert est.offset_s == pytest.approx(-0.3, abs=0.02) and est.observable
    for shift in (-0.15, 0.15):  # stable: shifting the data shifts the estimate by as much
        assert time_offset_hint(t_g + 0.3 + shift, v, t_i, w_true).offset_s == pytest.approx(
            est.offset_s - shift, abs=0.01
        )
    straight = np.c_[0 * t_g, 10 + 0 * t_g, 0 * t_g] + 0.05 * np.random.default_rng(0).standard_normal(
        (120, 3)
    )
    assert not time_offset_hint(t_g, straight, t_i, 0 * t_i + 1e-4).observable


# ------------------------------------------------------------------ the trust check


def _fake(err_filter: float, err_gnss: float, truth: bool = True):
    K = 50
    rng = np.random.default_rng(0)
    x_true = np.zeros((1, K + 1, 15))
    fixes = x_true[..., 6:9] + err_gnss / np.sqrt(3) * rng.standard_normal((1, K + 1, 3))
    x = x_true.copy()
    x[..., 6:9] += err_filter / np.sqrt(3) * rng.standard_normal((1, K + 1, 3))
    fixes[:, 0] = np.nan  # epoch 0 carries no measurement
    data = SimpleNamespace(
        model=SimpleNamespace(fixes=lambda z: z),
        z=fixes,
        groups={"pos": SimpleNamespace(idx=(6, 7, 8))},
        window=np.arange(K + 1) >= 1,
        has_truth=truth,
        x_true=x_true,
        extras={
            "p_true_antenna": x_true[0, :, 6:9],
            "fix_sigma_m": np.full((K + 1, 3), err_gnss / np.sqrt(3)),
            "start": "moving",
            "findings": [Finding("warning", "gravity reads -9.81 m/s² on z")],
        },
    )
    fr = SimpleNamespace(x=x, diverged=np.zeros(1, bool), label="KF")
    return SimpleNamespace(data=data, runs={"kf": fr})


@pytest.mark.parametrize("truth", [True, False])
def test_trust_check_warns_only_when_every_filter_is_much_worse_than_its_gnss(truth):
    good = trust_check(_fake(1.0, 5.0, truth))
    assert [f.level for f in good] == ["note"]
    bad = trust_check(_fake(5.0 * TRUST_FACTOR * 1.5, 5.0, truth))
    assert [f.level for f in bad] == ["note", "warning"]
    w = bad[1]
    assert "cannot be trusted" in w.text and ("no truth" in bad[0].text) != truth
    assert w.causes[0].startswith("the check before the run: gravity")  # the flagged check first
    assert any("mounting rotation" in c for c in w.causes) and any(
        "gnss_time_offset_s" in c for c in w.causes
    )
    assert "Likely causes: (1)" in str(w)


# ------------------------------------------------------------------ hardening, round three (issue 22)


def _twice(df: pd.DataFrame) -> pd.DataFrame:
    return df.loc[df.index.repeat(2)]


def _leap(df: pd.DataFrame) -> pd.DataFrame:
    df = df.copy()
    df.loc[40, "t_s"] = df.t_s[39]
    return df


def _zero_sigma(df: pd.DataFrame) -> pd.DataFrame:
    return df.assign(sigma_n_m=0.0)


def _nanoseconds(df: pd.DataFrame) -> pd.DataFrame:
    return df.assign(t_s=(df.t_s * 1e9).round().astype("int64"))


@needs_rtkx
@pytest.mark.parametrize(
    ("files", "change", "says"),
    [
        (("imu",), _twice, r"imu.csv: data rows 1 and 2 have the same time"),  # item 1
        (("gnss",), _twice, r"gnss.csv: data rows 1 and 2 have the same time"),  # item 2
        (("gnss",), _leap, r"gnss.csv: data rows 40 and 41 have the same time .*one row repeats"),  # item 3
        (
            ("gnss",),
            _zero_sigma,
            r"gnss.csv: sigma_n_m is below 1 mm on 90 of 90 fixes .*use_receiver_sigmas",
        ),
        (("imu", "gnss", "truth"), _nanoseconds, r"t_s must be seconds, but it looks like nanoseconds"),
    ],
    ids=["imu-twice", "gnss-twice", "leap-second", "sigma-0", "nanoseconds"],
)
def test_bad_recordings_give_one_line_and_exit_2(tmp_path, moving, capsys, files, change, says):
    """Issue 22 items 1-5 through the CLI: exit 2 and one line saying what to change (before:
    ZeroDivisionError, 'Maximum allowed size exceeded', 'SVD did not converge', a silent run
    with ANEES 1286, a misleading cause)."""
    for name in ("imu", "gnss", "truth"):
        df = pd.read_csv(moving / f"{name}.csv", comment="#")
        (change(df) if name in files else df).to_csv(tmp_path / f"{name}.csv", index=False)
    rc = main(
        ["run", "--scenario", "own-drive", "--filters", "kf", "--set", f"scenario.data_dir={tmp_path}"]
        + [f"--set=scenario.{k}={v}" for k, v in MOUNT.items()]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith("navlab: error: ") and re.search(says, err[0]), err[0]


@pytest.mark.parametrize("with_velocity", [True, False])
def test_outlier_check_flags_moved_fixes_and_little_else(with_velocity):
    from navlab.data.checks import fix_outliers

    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.07, 0.2, 600))
    v = np.c_[10 * np.sin(t / 20), 10 * np.cos(t / 20), 0 * t]  # E, N, U of the curve p (N, E, U)
    p = np.c_[200 * np.sin(t / 20), -200 * np.cos(t / 20), 0 * t] + rng.standard_normal((600, 3))
    moved = rng.random(600) < 0.1
    d = rng.standard_normal((moved.sum(), 3))
    p[moved] += d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(30, 100, (moved.sum(), 1))
    flags = fix_outliers(t, p, v if with_velocity else None, np.ones((600, 3)))
    assert flags[moved].all() and flags[~moved].mean() < 0.01
