from apphelpers import assert_clean, plotly_figs

PAGE = "pages/3_Sweep.py"


def test_sweep_contamination_small(open_page):
    at = open_page(PAGE, runs="4", flt=["kf", "chi2-kf"], swn="3", **{"sc.cv2d.epochs": "30"})
    assert_clean(at)
    assert at.selectbox(key="swp").value == "ol.mixture.contamination"
    at.button(key="run_sweep").click().run()
    assert_clean(at)
    lines, heat = plotly_figs(at)
    assert len(lines["data"]) == 2 and heat["data"][0]["type"] == "heatmap"
    at.selectbox(key="sw_v_metric").set_value("anis").run()
    assert_clean(at)
    assert plotly_figs(at)[0]["layout"]["yaxis"]["title"]["text"] == "ANIS"


def test_sweep_a_filter_parameter_and_bad_range(open_page):
    at = open_page(
        PAGE, runs="3", flt=["kf", "chi2-kf"], swn="2", swp="fp.chi2-kf.alpha", **{"sc.cv2d.epochs": "20"}
    )
    assert_clean(at)
    assert at.selectbox(key="swp").value == "fp.chi2-kf.alpha"
    at.number_input(key="sw.fp.chi2-kf.alpha.lo").set_value(0.2).run()
    at.number_input(key="sw.fp.chi2-kf.alpha.hi").set_value(0.1).run()
    assert not at.exception
    assert any("upper end" in e.value for e in at.error)
