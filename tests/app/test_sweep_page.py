from apphelpers import assert_clean, assert_progress_above_charts, plotly_figs

PAGE = "pages/3_Sweep.py"


def test_sweep_contamination_small(open_page):
    at = open_page(PAGE, runs="4", flt=["kf", "chi2-kf"], out="mixture", swn="3", **{"sc.cv2d.epochs": "30"})
    assert_clean(at)
    assert at.selectbox(key="swp").value == "ol.mixture.contamination"
    at.button(key="run_sweep").click().run()
    assert_clean(at)
    lines, heat = plotly_figs(at)
    assert len(lines["data"]) == 2 and heat["data"][0]["type"] == "heatmap"
    # the axis in words, not the widget id
    title = lines["layout"]["xaxis"]["title"]["text"]
    assert "outlier ratio" in title and "ol.mixture" not in title
    assert {"Sweep results (CSV)", "Table (LaTeX)"} <= {b.label for b in at.get("download_button")}
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


def test_two_d_sweep_heat_map_and_the_store_shows_it_again(open_page):
    q = {"runs": "3", "flt": ["kf", "huber-kf"], "swn": "2", "sw2": "true", "sw2n": "2"}
    q |= {"swp2": "fp.huber-kf.gamma", "sc.cv2d.epochs": "20"}
    at = open_page(PAGE, **q)
    assert_clean(at)
    assert at.selectbox(key="swp2").value == "fp.huber-kf.gamma"
    at.button(key="run_sweep").click().run()
    assert_clean(at)
    (heat,) = plotly_figs(at)
    assert heat["data"][0]["type"] == "heatmap"
    assert len(heat["data"][0]["x"]) == 2 and len(heat["data"][0]["y"]) == 2
    assert (
        "Huber" in heat["layout"]["yaxis"]["title"]["text"] or "γ" in heat["layout"]["yaxis"]["title"]["text"]
    )
    at.selectbox(key="sw_v_filter").set_value(at.selectbox(key="sw_v_filter").options[1]).run()
    assert_clean(at)
    # a new session on the same configuration: the finished points come from the store, no Run
    again = open_page(PAGE, **q)
    assert_clean(again)
    assert len(plotly_figs(again)) == 1
    assert any("from the store" in c.value for c in again.caption)


def test_sweep_caption_counts_tasks_not_a_wrong_product(open_page):
    """The plan line read '3 points × 2 filters × 4 runs = 6 tasks' (3 × 2 × 4 is not 6): a task is
    one point and one filter, with all the runs."""
    at = open_page(PAGE, runs="4", flt=["kf", "chi2-kf"], out="mixture", swn="3", **{"sc.cv2d.epochs": "30"})
    assert_clean(at)
    assert any(c.value.startswith("3 points × 2 filters, 4 runs each: 6 tasks, run ") for c in at.caption)


def test_sweep_progress_sits_under_run_not_below_the_charts(open_page):
    at = open_page(PAGE, runs="3", seed="9", flt=["kf"], swn="2", **{"sc.cv2d.epochs": "20"})
    at.button(key="run_sweep").click().run()
    assert_clean(at)
    assert_progress_above_charts(at)
    assert not [b for b in at.button if b.label == "Stop"]  # the sweep ended: nothing to stop
