from apphelpers import assert_clean, assert_progress_above_charts, plotly_figs

from navlab.ui.views import noise_preset

PAGE = "pages/2_Noise.py"


def test_noise_page_has_the_shared_defaults_and_offers_its_preset(open_page):
    """#16 item 4: a link means the same experiment on every page (the Compare defaults); the
    Noise page's suggestion (σ step + isolated outliers) is a button."""
    at = open_page(PAGE)
    assert_clean(at)
    assert at.selectbox(key="noise").value == "step"
    assert at.selectbox(key="out").value == "none"
    assert at.multiselect(key="flt").value == ["kf", "sage-husa", "vb-akf", "hakf", "oracle-kf"]
    at.button(key="noise_preset").click().run()
    assert_clean(at)
    assert at.selectbox(key="noise").value == "step"
    assert at.selectbox(key="out").value == "isolated"
    assert at.number_input(key="runs").value == 50
    pre = noise_preset()
    assert at.multiselect(key="flt").value == pre["flt"] and "sage-husa" in pre["flt"]


def test_noise_page_small_run(open_page):
    at = open_page(
        PAGE,
        runs="5",
        flt=["kf", "oracle-kf", "sage-husa"],
        noise="step",
        out="isolated",
        **{"sc.cv2d.epochs": "80"},
    )
    assert_clean(at)
    assert at.selectbox(key="noise").value == "step"
    at.button(key="run_noise").click().run()
    assert_clean(at)
    fig, _internals = plotly_figs(at)
    names = [t.get("name", "") for t in fig["data"]]
    assert names[-1] == "true R(t) (schedule)"  # the truth drawn last, on top
    assert "Sage–Husa AKF R̂" in names
    assert any(t["type"] == "bar" for t in fig["data"])  # outlier epochs marked on the time axis
    assert any("epochs contaminated in most runs: 20, 25" in c.value for c in at.caption)
    tab = at.table[0].value
    assert "Oracle KF" in tab.index and tab.shape[1] == 2  # one R̂ error column per channel
    at.toggle(key="noise_v_std").set_value(True).run()
    assert_clean(at)
    assert "σ" in plotly_figs(at)[0]["layout"]["yaxis"]["title"]["text"]
    # filter internals: sage-husa reports its statistics; the chosen one is plotted per filter
    stats = at.selectbox(key="noise_v_stat").options
    assert stats
    at.selectbox(key="noise_v_stat").set_value(stats[-1]).run()
    assert_clean(at)
    assert plotly_figs(at)[1]["layout"]["title"]["text"].startswith(stats[-1])


def test_noise_page_internals_show_fading_with_threshold(open_page):
    at = open_page(PAGE, runs="3", flt=["kf", "mfukf"], noise="step", **{"sc.cv2d.epochs": "40"})
    at.button(key="run_noise").click().run()
    assert_clean(at)
    at.selectbox(key="noise_v_stat").set_value("gamma").run()
    assert_clean(at)
    names = [t.get("name", "") for t in plotly_figs(at)[1]["data"]]
    assert any("MFUKF" in n or "mfukf" in n for n in names)
    assert "mfukf: threshold" in names


def test_noise_page_without_outliers_draws_no_empty_strip(open_page):
    """A run without outliers has no outlier strip under the R̂ panels (it was an empty panel),
    and the caption names the outlier model instead of repeating itself."""
    at = open_page(PAGE, runs="3", flt=["kf", "sage-husa"], **{"sc.cv2d.epochs": "40"})
    at.button(key="run_noise").click().run()
    assert_clean(at)
    fig = plotly_figs(at)[0]
    assert not any(t["type"] == "bar" for t in fig["data"])
    assert any(
        c.value == "Outliers on this channel: no outliers on this channel (outlier model `none`)"
        for c in at.caption
    )


def test_noise_page_progress_sits_under_run_not_below_the_charts(open_page):
    """The progress bar (and Stop) came after the last chart, out of sight after pressing Run."""
    at = open_page(PAGE, runs="3", seed="5", flt=["kf", "sage-husa"], **{"sc.cv2d.epochs": "40"})
    at.button(key="run_noise").click().run()
    assert_clean(at)
    assert_progress_above_charts(at)
