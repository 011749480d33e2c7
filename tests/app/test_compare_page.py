import numpy as np
from apphelpers import SMALL, assert_clean, plotly_figs

import navlab.ui.runner as runner

PAGE = "pages/1_Compare.py"


def test_compare_renders_defaults_without_running(open_page):
    at = open_page(PAGE)
    assert_clean(at)
    # #21: the default experiment estimates R, on a schedule whose R changes
    assert at.multiselect(key="flt").value == ["kf", "sage-husa", "vb-akf", "hakf", "oracle-kf"]
    assert at.button(key="run_compare")
    (preview,) = plotly_figs(at)  # nothing runs before Run: only the schedule preview
    assert preview["layout"]["title"]["text"].startswith("Noise schedule 'step'")


def test_query_params_initialise_the_widgets(open_page):
    at = open_page(
        PAGE,
        runs="17",
        seed="5",
        flt=["kf", "chi2-kf"],
        noise="step",
        out="mixture",
        **{"ol.mixture.contamination": "0.2", "ns.step.factor": "4"},
    )
    assert_clean(at)
    assert at.number_input(key="runs").value == 17
    assert at.number_input(key="seed").value == 5
    assert at.multiselect(key="flt").value == ["kf", "chi2-kf"]
    assert at.selectbox(key="noise").value == "step"
    assert at.number_input(key="ol.mixture.contamination").value == 0.2
    assert at.number_input(key="ns.step.factor").value == 4.0


def test_small_run_completes_with_charts_and_table(open_page):
    at = open_page(PAGE, seed="11", **SMALL)
    at.button(key="run_compare").click().run()
    assert_clean(at)
    figs = plotly_figs(at)
    assert len(figs) == 4  # error vs time, R vs R-hat, NIS vs chi2, the single-run view
    types = {t["type"] for f in figs for t in f["data"]}
    assert types <= {"scatter", "scattergl"}
    names = [t.get("name", "") for t in figs[0]["data"]]
    assert {"KF", "Oracle KF", "χ²-gated KF"} <= set(names)
    # a spread band: a trace filled to the previous one
    assert any(t.get("fill") == "tonexty" for t in figs[0]["data"])
    table = at.table[0].value
    assert list(table.index) == ["KF", "Oracle KF", "χ²-gated KF"]
    rmse = np.array([float(c.split()[0]) for c in table["RMSE position (m)"]])  # "v [lo, hi]"
    assert np.all(np.isfinite(rmse)) and rmse[1] < rmse[0]  # the oracle beats the KF
    assert list(table.columns)[:2] == ["RMSE position (m)", "vs KF"]  # the verdict beside its metric
    vs = table["vs KF"]
    assert vs.iloc[0] == "reference" and "no test" in vs.iloc[1]  # 6 runs: too few for a test
    assert any("too few runs for an interval" in c.value for c in at.caption)
    assert any("6/6 runs (complete)" in c.value for c in at.caption)
    labels = [b.label for b in at.get("download_button")]
    assert {
        "Configuration (JSON)",
        "Metrics (CSV)",
        "RMSE per epoch (CSV)",
        "Table (LaTeX)",
        "Table (Markdown)",
    } <= set(labels)
    assert {"Notebook (.ipynb)", "Script (.py)", "SVG", "PNG"} <= set(labels)


def test_view_controls_do_not_recompute(open_page, monkeypatch):
    at = open_page(PAGE, seed="12", **SMALL)
    at.button(key="run_compare").click().run()
    assert_clean(at)
    calls = []
    real = runner.iter_chunks
    monkeypatch.setattr(runner, "iter_chunks", lambda *a, **k: calls.append(1) or real(*a, **k))
    at.toggle(key="compare_v_logerr").set_value(True).run()
    at.selectbox(key="compare_v_ch").set_value(1).run()
    at.selectbox(key="compare_v_group").set_value("vel").run()
    assert_clean(at)
    assert calls == []
    figs = plotly_figs(at)
    assert figs[0]["layout"]["yaxis"]["type"] == "log"
    assert "velocity" in figs[0]["layout"]["yaxis"]["title"]["text"]
    assert "Channel y" in figs[1]["layout"]["title"]["text"]


def test_changed_parameter_needs_a_new_run(open_page):
    at = open_page(PAGE, seed="13", **SMALL)
    at.button(key="run_compare").click().run()
    assert len(plotly_figs(at)) == 4
    at.number_input(key="seed").set_value(14).run()
    assert_clean(at)
    # the old results are not shown for a new configuration (only the schedule preview)
    assert len(plotly_figs(at)) == 1
    assert any("Press **Run**" in i.value for i in at.info)


def test_bad_combination_is_a_message_not_a_traceback(open_page):
    at = open_page(PAGE, flt=["kf"], runs="5")
    at.multiselect(key="flt").set_value([]).run()
    assert not at.exception
    assert any("at least one filter" in e.value for e in at.error)


def test_changing_scenario_takes_its_default_filters(open_page):
    at = open_page(PAGE)
    other = [o for o in at.selectbox(key="scn").options if o != "cv2d"]
    if not other:
        return
    at.selectbox(key="scn").set_value(other[0]).run()
    assert not at.exception
    from navlab.scenarios import scenario_registry

    want = [k for k in scenario_registry()[other[0]].default_filters]
    assert at.multiselect(key="flt").value == want


def test_run_without_live_updates(open_page, monkeypatch):
    sizes = []
    real = runner.iter_chunks

    def spy(spec, start=None, first_chunk=None, on_epoch=None):
        for r in real(spec, start, first_chunk, on_epoch):
            sizes.append(r.done_runs)
            yield r

    monkeypatch.setattr(runner, "iter_chunks", spy)
    at = open_page(PAGE, seed="15", **SMALL)
    at.toggle(key="compare_live").set_value(False).run()
    at.button(key="run_compare").click().run()
    assert_clean(at)
    assert sizes == [6]  # one batch
    assert len(plotly_figs(at)) == 4


def test_a_link_that_would_exhaust_memory_is_refused_with_a_message(open_page):
    """/Compare?flt=kf&runs=5000&sc.cv2d.epochs=100000 once grew the server to 9.9 GB in 21 s."""
    at = open_page(PAGE, flt=["kf"], runs="5000", **{"sc.cv2d.epochs": "100000"})
    at.button(key="run_compare").click().run()
    assert not at.exception
    (err,) = [e.value for e in at.error]
    assert "would hold about" in err and "memory budget" in err and "fewer runs or epochs" in err
    assert runner.ledger().in_use == 0  # nothing left reserved


# ------------------------------------------------------------------ #16 teaching and presenting


def test_single_run_view_shows_one_run_with_a_player(open_page):
    from navlab.experiment import ExperimentSpec, run_experiment
    from navlab.ui.single import most_different_run

    at = open_page(PAGE, seed="31", **SMALL)
    at.button(key="run_compare").click().run()
    assert_clean(at)
    one = plotly_figs(at)[-1]
    assert one["layout"]["title"]["text"].startswith("Monte Carlo run ")
    assert one["layout"]["updatemenus"][0]["buttons"][0]["label"] == "▶ play"
    assert len(one["layout"]["sliders"][0]["steps"]) == len(one["frames"]) > 10
    names = {t.get("name", "") for t in one["data"]}
    assert {"KF", "Oracle KF", "χ²-gated KF", "truth (the zero line)"} <= names
    # by default the run where the filters differ most (the library's choice on the same runs)
    spec = ExperimentSpec(filters=("kf", "oracle-kf", "chi2-kf"), runs=6, seed=31, epochs=30)
    want = int(run_experiment(spec).data.runs[most_different_run(run_experiment(spec), "pos")])
    assert one["layout"]["title"]["text"].startswith(f"Monte Carlo run {want},")
    at.radio(key="compare_one_how").set_value("run number").run()
    at.number_input(key="compare_one_run").set_value(2).run()
    assert_clean(at)
    assert plotly_figs(at)[-1]["layout"]["title"]["text"].startswith("Monte Carlo run 2,")
    # run 2 is batch index 2: no "(batch index 2)" repeating the number
    assert any(c.value.startswith("Run 2 · RMSE position in this run: ") for c in at.caption)
    at.multiselect(key="compare_one_flt").set_value(["kf"]).run()
    names = {t.get("name", "") for t in plotly_figs(at)[-1]["data"]}
    assert "KF" in names and "Oracle KF" not in names


def test_rejected_link_values_are_named_with_the_reason(open_page):
    at = open_page(PAGE, runs="-1", flt=["kf", "unknown"], out="mixture", **{"ol.mixture.contamination": "5"})
    assert not at.exception
    (w,) = [w.value for w in at.warning if "were not used" in w.value]
    assert "`runs=-1`: Monte Carlo runs must be from 1 to 5000" in w
    assert "`flt=unknown`: no filter is registered under this key" in w
    assert "`ol.mixture.contamination=5`: contamination must be from 0 to 0.5" in w
    assert at.number_input(key="runs").value == 100  # the default, as the notice says
    at.number_input(key="seed").set_value(3).run()  # the notice stays until the experiment changes
    assert not [w for w in at.warning if "were not used" in w.value]


def test_go_link_runs_once_on_open(open_page):
    at = open_page(PAGE, go="1", seed="32", **SMALL)
    assert_clean(at)
    assert len(plotly_figs(at)) == 4  # ran without a click
    assert "go" not in at.query_params


def test_best_value_is_highlighted_only_where_the_test_backs_it(open_page):
    at = open_page(PAGE, seed="33", **SMALL)  # 6 runs: too few for a test, nothing highlighted
    at.button(key="run_compare").click().run()
    assert any("no column has one at this run count" in c.value for c in at.caption)
    at = open_page(PAGE, seed="33", runs="60", **{"sc.cv2d.epochs": "30"})
    at.button(key="run_compare").click().run()
    assert_clean(at)
    assert any("Bold on green" in c.value and "no column" not in c.value for c in at.caption)


def test_presentation_mode_sizes_charts_and_hides_the_exports(open_page):
    at = open_page(PAGE, present="1", seed="34", **SMALL)
    at.button(key="run_compare").click().run()
    assert_clean(at)
    figs = plotly_figs(at)
    assert all(f["layout"]["height"] >= 700 for f in figs)
    labels = {b.label for b in at.get("download_button")}
    assert "SVG" not in labels and "PNG" not in labels
    links = [el for el in at.get("page_link")]
    assert links and all("present=1" in el.proto.page or "present" in str(el.proto) for el in links)
