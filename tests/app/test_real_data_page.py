"""AppTest of the Real data page: renders, runs short segments, reports bad uploads."""

from __future__ import annotations

import numpy as np
import pytest
from apphelpers import SMALL, assert_clean, plotly_figs

from navlab.data import data_root
from navlab.data.loaders import RTKX_DIR, SMARTLOC_DIR

PAGE = "pages/6_Real_data.py"
ROOT = data_root()
needs_data = pytest.mark.skipif(
    not ((ROOT / RTKX_DIR).is_dir() and (ROOT / SMARTLOC_DIR).is_dir()),
    reason=f"real data not found under {ROOT} (set NAVLAB_DATA)",
)


def test_renders_without_running(open_page):
    at = open_page(PAGE)
    assert_clean(at)
    assert at.selectbox(key="rd_rec").value == "drive0708"
    assert at.button(key="rd_run")
    assert not plotly_figs(at)
    assert any("BSD-3-Clause" in i.value for i in at.info)  # source and licence shown


def test_the_first_view_warms_the_default_drive_run(open_page):
    """The page's background warm is a tiny run of what its Run button runs by default."""
    from navlab.experiment import plan
    from navlab.ui import realdata as R
    from navlab.ui.frame import warm_run_once

    at = open_page(PAGE)
    spec = R.warm_spec()
    assert spec.scenario == at.selectbox(key="rd_rec").value == "drive0708"
    assert list(spec.filters) == at.multiselect(key="rd_flt_drive0708").value and spec.runs == 1
    assert warm_run_once(spec.to_json()).name == "navlab-warm-page"  # started once per process
    if (ROOT / RTKX_DIR).is_dir():
        plan(spec)  # a valid experiment (a NavlabError otherwise)


@needs_data
@pytest.mark.slow
def test_short_drive_segment_runs(open_page):
    at = open_page(PAGE)
    at.number_input(key="rd_ep_drive0708").set_value(15).run()
    at.multiselect(key="rd_flt_drive0708").set_value(["kf", "huber-kf", "vb-akf"]).run()
    at.button(key="rd_run").click().run()
    assert_clean(at)
    table = at.table[0].value
    assert list(table.index) == ["KF", "HKF (Huber)", "AKF (VB)"]
    # "v" or "v [lo, hi]": three significant figures with its interval where there is one
    med = np.array([float(c.split()[0]) for c in table["median horizontal error (m)"]])
    assert np.all(np.isfinite(med)) and np.all(med < 10)
    figs = plotly_figs(at)
    assert len(figs) >= 3  # track, error vs time, R̂, flags
    track = figs[0]
    names = [t.get("name") for t in track["data"]]
    assert "truth" in names and "GNSS fixes (aiding)" in names
    assert track["layout"]["xaxis"]["title"]["text"] == "east (m)"
    assert all(t["type"] == "scattergl" for f in figs for t in f["data"])


@needs_data
def test_short_smartloc_segment_runs(open_page):
    at = open_page(PAGE)
    at.selectbox(key="rd_rec").set_value("smartloc-berlin").run()
    at.number_input(key="rd_ep_smartloc-berlin").set_value(40).run()
    at.multiselect(key="rd_flt_smartloc-berlin").set_value(["wls", "ekf", "huber-kf"]).run()
    at.button(key="rd_run").click().run()
    assert_clean(at)
    table = at.table[0].value
    assert "WLS (per epoch)" in table.index
    assert all(np.isfinite(float(c.split()[0])) for c in table["median horizontal error (m)"])
    assert any("CC BY-SA 4.0" in i.value for i in at.info)


def test_bad_upload_names_the_file_line_and_column():
    """The page shows this message with st.error (AppTest cannot drive file_uploader)."""
    from navlab.errors import NavlabError
    from navlab.ui import realdata as R
    from navlab.ui.uploads import SessionUploads

    imu = b"t_s,f_x_mps2,f_y_mps2,f_z_mps2,w_x_radps,w_y_radps\n0,0,0,9.8,0,0\n"
    with pytest.raises(NavlabError, match=r"uploaded imu.csv: line 1 \(header\) lacks column\(s\) w_z_radps"):
        R.save_upload(imu, b"t_s,lat_deg,lon_deg,h_m\n0,40,-105,1600\n", uploads=SessionUploads())


def test_url_sets_the_recording_and_its_settings(open_page):
    """Every setting of the page is bound to the URL: a shared link opens the same run."""
    at = open_page(
        PAGE,
        rd_rec="smartloc-berlin",
        rd_seed="7",
        **{"rd_ep_smartloc-berlin": "40", "rd_flt_smartloc-berlin": ["wls", "ekf"], "rd_alpha_sl": "0.05"},
    )
    assert_clean(at)
    assert at.selectbox(key="rd_rec").value == "smartloc-berlin"
    assert at.number_input(key="rd_seed").value == 7
    assert at.number_input(key="rd_ep_smartloc-berlin").value == 40
    assert at.multiselect(key="rd_flt_smartloc-berlin").value == ["wls", "ekf"]
    assert at.slider(key="rd_alpha_sl").value == pytest.approx(0.05)


def test_rejected_link_values_get_the_usual_notice(open_page):
    """Issue 22 item 10: /Real_data?rd_rec=../../../etc/passwd was ignored without the notice."""
    at = open_page(
        PAGE, rd_rec="../../../etc/passwd", rd_seed="9007199254740992", **{"rd_ep_drive0708": "200001"}
    )
    assert not at.exception
    (w,) = [w.value for w in at.warning if "were not used" in w.value]
    assert (
        "`rd_rec=../../../etc/passwd`: no such recording "
        "(one of: drive0708, smartloc-berlin, upload, upload-pr)" in w
    )
    assert (
        "`rd_seed=9007199254740992`: the seed must be from 0 to 9007199254740991" in w
    )  # whole, not 9.0e+15
    assert "`rd_ep_drive0708=200001`: epochs must be from 0 to 200000" in w
    assert at.selectbox(key="rd_rec").value == "drive0708"


def test_seed_and_epochs_ranges_are_the_clis(open_page):
    """Issue 22 item 10: one seed range and one epoch maximum for the CLI and every page."""
    from navlab.cli import main
    from navlab.params import MAX_EPOCHS, SEED_MAX

    at = open_page(PAGE, rd_seed=str(SEED_MAX), **{"rd_ep_drive0708": str(MAX_EPOCHS)})
    assert at.number_input(key="rd_seed").value == SEED_MAX
    assert at.number_input(key="rd_ep_drive0708").value == MAX_EPOCHS
    assert not [w for w in at.warning if "were not used" in w.value]
    assert main(["run", "--filters", "kf", "--runs", "1", "--epochs", "3", "--seed", str(SEED_MAX)]) == 0
    assert main(["run", "--filters", "kf", "--runs", "1", "--epochs", "3", "--seed", str(SEED_MAX + 1)]) == 2
    at = open_page("pages/1_Compare.py", seed=str(SEED_MAX), **SMALL)  # the CLI's largest seed as a link
    assert at.number_input(key="seed").value == SEED_MAX and not at.exception
    assert not [w for w in at.warning if "were not used" in w.value]
    assert main(["run", "--filters", "kf", "--runs", "1", "--epochs", str(MAX_EPOCHS + 1)]) == 2
