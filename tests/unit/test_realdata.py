"""Real-data pipeline: INS on the static start, loosely coupled KF, the models' Jacobians, wls,
and robust filters against per-epoch WLS on smartloc-berlin. Reads ../shared/data (skips if absent).
"""

import numpy as np
import pytest

from navlab.data import data_root
from navlab.data.loaders import RTKX_DIR, SMARTLOC_DIR
from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec, run_experiment
from navlab.filters.base import LinearModel, SideInfo, make_filter
from navlab.ins.earth import OMEGA_IE_RADPS

ROOT = data_root()
needs_rtkx = pytest.mark.skipif(
    not (ROOT / RTKX_DIR).is_dir(), reason=f"real data not found: {ROOT / RTKX_DIR} (set NAVLAB_DATA)"
)
needs_smartloc = pytest.mark.skipif(
    not (ROOT / SMARTLOC_DIR).is_dir(), reason=f"real data not found: {ROOT / SMARTLOC_DIR} (set NAVLAB_DATA)"
)


def _metric(res, key, metric):
    df = res.metrics()
    return float(df[(df["filter"] == key) & (df.metric == metric)].value.iloc[0])


@needs_rtkx
def test_free_ins_on_the_static_start_stays_within_mems_drift():
    from navlab.data import rtkx_drive_0708
    from navlab.ins import align_static, init_state, propagate_block
    from navlab.ins.earth import radii

    rec = rtkx_drive_0708()
    imu = rec.imu
    t = imu.t_s.to_numpy()
    f = imu[["f_x_mps2", "f_y_mps2", "f_z_mps2"]].to_numpy()
    w = imu[["w_x_radps", "w_y_radps", "w_z_radps"]].to_numpy()
    lat, lon, h = np.radians(rec.gnss.lat_deg[0]), np.radians(rec.gnss.lon_deg[0]), rec.gnss.h_m[0]
    a = t < 20.0  # align on 3–20 s, navigate freely over 20–36 s (the car starts at ≈38 s)
    al = align_static(f[a], w[a], lat, h, 0.0, C_bv=rec.C_bv)
    assert abs(al.pitch_deg) < 3 and abs(al.roll_deg) < 3  # the README's mounting: a level car
    ba = al.accel_norm_minus_gravity_mps2 * al.f_b_mean_mps2 / np.linalg.norm(al.f_b_mean_mps2)
    s = init_state(
        lat, lon, h, np.zeros(3), al.C_bn, bias_g_radps=al.gyro_bias_radps, bias_a_mps2=ba, t_s=20.0
    )
    b = (t >= 20.0) & (t < 36.0)
    s, _ = propagate_block(s, t[b], f[b], w[b], t_end_s=36.0)
    R_Mh, R_Nh = radii(lat, h)
    drift = np.hypot((s.lat_rad[0] - lat) * R_Mh, (s.lon_rad[0] - lon) * R_Nh * np.cos(lat))
    # MEMS bound: accel bias instability δa = 0.02 m/s², residual gyro bias δε = 0.02 °/s
    T, g = 16.0, 9.8
    bound = 0.5 * 0.02 * T**2 + g * np.radians(0.02) * T**3 / 6
    assert drift < bound
    assert np.linalg.norm(s.v_enu_mps[0]) < 0.02 * T + g * np.radians(0.02) * T**2 / 2


@needs_rtkx
def test_lc_kf_with_clean_gnss_beats_the_gnss_noise():
    spec = ExperimentSpec(
        scenario="drive0708",
        filters=("kf", "wls"),
        runs=2,
        seed=2,
        outliers="none",
        scenario_params={"epochs": 60, "sigma_m": 1.0},
    )
    res = run_experiment(spec)
    # 3-D GNSS noise RMS = √3 σ; the INS-aided KF must do better, the per-epoch solve cannot
    assert _metric(res, "kf", "rmse_pos") < 0.8 * np.sqrt(3)
    assert _metric(res, "wls", "rmse_pos") == pytest.approx(np.sqrt(3), rel=0.2)
    assert _metric(res, "kf", "diverged") == 0


@needs_rtkx
def test_ins_model_f_and_nhc_jacobian():
    from navlab.ins.lc import InsGnssModel
    from navlab.scenarios.drive0708 import drive_setup

    _, setup, ref = drive_setup("", 30, 10.0)
    model = InsGnssModel(setup, ref, np.ones(3), nhc_sigma_mps=0.2)
    # the reference propagated by f lands on the reference (the total-state chart round-trips)
    k = 20
    x = np.r_[np.zeros(3), ref.v[0, k - 1], ref.p[0, k - 1], ref.bias_g[0, k - 1], ref.bias_a[0, k - 1]]
    x1 = model.f(x[None], k)[0]
    np.testing.assert_allclose(x1[6:9], ref.p[0, k], atol=0.3)  # the reference got its update
    assert np.abs(x1[0:3]).max() < np.radians(0.5)
    # NHC Jacobian against central differences
    # (at a small attitude offset: the a-columns are first order in a, as the filters keep a ≈ 0)
    x = x + np.r_[np.radians([0.05, -0.03, 0.1]), [0.2, -0.1, 0.05], np.zeros(9)]
    H = model.H(x[None], k)[0]
    eps = np.r_[[1e-6] * 3, [1e-5] * 3, [1e-3] * 9]
    J = np.stack(
        [
            (model.h((x + e)[None], k)[0] - model.h((x - e)[None], k)[0]) / (2 * e[j])
            for j, e in enumerate(np.diag(eps))
        ],
        axis=1,
    )
    np.testing.assert_allclose(H[3:5, :6], J[3:5, :6], atol=2e-3 * np.abs(J[3:5, :6]).max())
    np.testing.assert_allclose(H[:3], J[:3], atol=1e-6)


def test_wls_returns_the_measurement_and_solves_ranges():
    # position measured directly: the per-epoch solve is the measurement itself
    lm = LinearModel(np.eye(4), np.eye(4), np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]]), np.eye(2))
    f = make_filter("wls")
    st = f.init(lm, np.zeros((3, 4)), np.eye(4))
    z = np.array([[1.0, 2.0], [3.0, -4.0], [np.nan, 5.0]])
    side = SideInfo(np.ones((3, 2)), np.zeros((3, 2)), np.zeros((3, 2), bool))
    st, out = f.update(lm, f.predict(lm, st, 1), 1, z, side)
    np.testing.assert_allclose(out.x[:2, [0, 2]], z[:2], atol=1e-6)
    assert out.x[2, 2] == pytest.approx(5.0, abs=1e-6) and out.x[2, 0] == pytest.approx(0.0, abs=1e-6)

    # ranges to four anchors (nonlinear): Gauss–Newton finds the true point
    anchors = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0]])

    class Ranges:
        n, m, linear = 2, 4, False
        R0 = np.eye(4)

        def h(self, x, k):
            return np.linalg.norm(anchors[None] - x[:, None, :], axis=-1)

        def H(self, x, k):
            d = x[:, None, :] - anchors[None]
            return d / np.linalg.norm(d, axis=-1, keepdims=True)

    truth = np.array([[30.0, 60.0]])
    model = Ranges()
    st = f.init(model, np.array([[50.0, 50.0]]), np.eye(2))
    _, out = f.update(model, st, 1, model.h(truth, 1), side)
    np.testing.assert_allclose(out.x, truth, atol=1e-6)


def test_sagnac_term_sign():
    from navlab.scenarios.smartloc_berlin import C_LIGHT, geometric_range

    r = np.array([6.37e6, 0.0, 0.0])
    sat = np.array([[2.0e7, 1.0e7, 0.0]])  # east of the receiver: the Earth turns towards it
    rng, _ = geometric_range(sat, r)
    geo = np.linalg.norm(sat[0] - r)
    # RTKLIB geodist: r + ω (x_s y_r − y_s x_r)/c
    assert rng[0] - geo == pytest.approx(OMEGA_IE_RADPS * (0 - 1.0e7 * 6.37e6) / C_LIGHT)


@needs_smartloc
def test_smartloc_robust_filter_beats_per_epoch_wls():
    spec = ExperimentSpec(
        scenario="smartloc-berlin",
        filters=("wls", "ekf", "huber-kf"),
        runs=1,
        scenario_params={"epochs": 400},
    )
    res = run_experiment(spec)
    wls = _metric(res, "wls", "h_err_median")
    best = min(_metric(res, k, "h_err_median") for k in ("huber-kf",))
    assert 8.0 < wls < 40.0  # the per-epoch fix in the canyon (README: 16 m with the C/N0 model)
    assert best < 0.85 * wls


@needs_rtkx
def test_generic_folder_runs_through_the_drive_scenario(tmp_path):
    """The rtkx drive exported in the generic CSV format (vehicle axes, noisy fixes) runs end to end
    through own-drive (the fixes as recorded); drive0708 refuses the folder and names own-drive."""
    import pandas as pd

    from navlab.data import rtkx_drive_0708

    r = rtkx_drive_0708()
    imu = r.imu[r.imu.t_s < 90]
    f = imu[["f_x_mps2", "f_y_mps2", "f_z_mps2"]].to_numpy() @ r.C_bv.T
    w = imu[["w_x_radps", "w_y_radps", "w_z_radps"]].to_numpy() @ r.C_bv.T
    cols = ("f_x_mps2", "f_y_mps2", "f_z_mps2", "w_x_radps", "w_y_radps", "w_z_radps")
    pd.DataFrame({"t_s": imu.t_s, **dict(zip(cols, np.c_[f, w].T, strict=True))}).to_csv(
        tmp_path / "imu.csv", index=False
    )
    gn = r.gnss[r.gnss.t_s < 90]
    rng = np.random.default_rng(0)
    pd.DataFrame(
        {
            "t_s": gn.t_s,
            "lat_deg": gn.lat_deg + 2 * rng.standard_normal(len(gn)) / 111e3,
            "lon_deg": gn.lon_deg + 2 * rng.standard_normal(len(gn)) / 85e3,
            "h_m": gn.h_m,
        }
    ).to_csv(tmp_path / "gnss.csv", index=False)
    gn[["t_s", "lat_deg", "lon_deg", "h_m"]].to_csv(tmp_path / "truth.csv", index=False)
    spec = ExperimentSpec(
        scenario="own-drive",
        filters=("kf", "wls"),
        runs=1,
        scenario_params={"data_dir": str(tmp_path)},
    )
    with pytest.raises(NavlabError, match="own-drive"):
        run_experiment(spec.replace(scenario="drive0708"))
    res = run_experiment(spec)
    assert res.data.has_truth and not res.data.outlier_mask.any()
    # noisy fixes of ≈2 m per horizontal axis: the INS-aided KF smooths them, WLS returns them
    assert _metric(res, "kf", "h_err_median") < 0.8 * _metric(res, "wls", "h_err_median")
    (tmp_path / "truth.csv").unlink()
    res = run_experiment(spec)
    assert not res.data.has_truth and _metric(res, "kf", "diverged") == 0


def test_wls_huber_downweights_a_gross_range_error():
    anchors = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0], [50.0, -80.0]])

    class Ranges:
        n, m, linear = 2, 5, False
        R0 = np.eye(5)

        def h(self, x, k):
            return np.linalg.norm(anchors[None] - x[:, None, :], axis=-1)

        def H(self, x, k):
            d = x[:, None, :] - anchors[None]
            return d / np.linalg.norm(d, axis=-1, keepdims=True)

    model = Ranges()
    truth = np.array([[30.0, 60.0]])
    z = model.h(truth, 1)
    z[0, 4] += 40.0  # one gross error
    side = SideInfo(np.ones((1, 5)), np.zeros((1, 5)), np.zeros((1, 5), bool))
    plain, robust = make_filter("wls"), make_filter("wls", {"huber_k": 1.5, "iterations": 30})
    _, o1 = plain.update(model, plain.init(model, np.array([[50.0, 50.0]]), np.eye(2)), 1, z, side)
    _, o2 = robust.update(model, robust.init(model, np.array([[50.0, 50.0]]), np.eye(2)), 1, z, side)
    e1, e2 = np.linalg.norm(o1.x - truth), np.linalg.norm(o2.x - truth)
    assert e2 < 0.2 * e1
    assert o2.weights[0, 4] < 0.2 and o2.flags[0, 4] == 1 and o1.weights[0, 4] == 1.0


def test_the_page_cli_line_repeats_the_run_exactly(tmp_path):
    """The Real data page's CLI line parses back into the page's spec (data_dir and every changed
    parameter included), and an upload's epochs default to the whole recording.
    """
    import shlex

    from navlab.cli import _spec_from_args, build_parser
    from navlab.experiment import plan
    from navlab.ui import realdata as R

    sp = {
        "data_dir": str(tmp_path / "my drive"),
        "imu_rate_hz": 0.0,
        "gnss_time_offset_s": 0.05,
        "add_noise": False,
    }
    spec = R.build_spec(
        "upload",
        ["kf", "irakf"],
        epochs=R.epochs_default("upload"),
        runs=3,
        seed=7,
        contamination=0.1,
        scenario_params=sp,
    )
    line = R.cli_line(spec)
    assert "scenario.imu_rate_hz=0.0" in line
    back = _spec_from_args(build_parser().parse_args(shlex.split(line)[3:]))
    assert back.scenario == spec.scenario and back.filters == spec.filters
    assert (back.runs, back.seed, back.contamination, back.outlier_scale) == (3, 7, 0.1, 10.0)
    assert plan(back).scenario.params == plan(spec).scenario.params  # data_dir included
    assert R.epochs_default("upload") == 0


def test_the_pseudorange_upload_cli_line_repeats_the_run_exactly(tmp_path):
    """The pseudorange upload's CLI line: scenario own-pseudoranges, its folder and height aiding."""
    import shlex

    from navlab.cli import _spec_from_args, build_parser
    from navlab.ui import realdata as R

    sp = {"data_dir": str(tmp_path / "my pr"), "height_aiding": "map-prior", "height_m": 74.5}
    spec = R.build_spec("upload-pr", ["wls", "ekf"], epochs=R.epochs_default("upload-pr"), scenario_params=sp)
    assert spec.scenario == "own-pseudoranges" and R.epochs_default("upload-pr") == 0
    line = R.cli_line(spec)
    back = _spec_from_args(build_parser().parse_args(shlex.split(line)[3:]))
    assert back.scenario == "own-pseudoranges" and back.filters == ("wls", "ekf")
    assert {k: back.scenario_params[k] for k in sp} == sp
