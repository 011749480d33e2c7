from apphelpers import assert_clean, plotly_figs

from navlab import tune as TU

PAGE = "pages/7_Tune.py"
Q = {
    "runs": "10",
    "flt": ["kf", "huber-kf", "chi2-kf"],
    "sc.cv2d.epochs": "20",
    "tn_budget": "3",
    "tn_train_runs": "4",
}


def test_tune_page_table_landscapes_and_compare_button(open_page):
    at = open_page(PAGE, **Q)
    assert_clean(at)
    assert any("Run tuning" in i.value for i in at.info)
    at.button(key="run_tune").click().run()
    assert_clean(at)
    (table,) = at.table
    df = table.value
    assert list(df.index) == ["KF", "HKF (Huber)", "χ²-gated KF"]
    assert any(c.startswith("test RMSE") and c.endswith("tuned") for c in df.columns)
    assert "[" in df.iloc[1, 2] or "[" in df.iloc[1, 3]  # intervals in the cells
    figs = plotly_figs(at)
    assert len(figs) == 2  # huber-kf (1 parameter) and chi2-kf (2 parameters)
    assert figs[0]["layout"]["xaxis"]["title"]["text"] == "gamma"
    assert {figs[1]["layout"]["xaxis"]["title"]["text"], figs[1]["layout"]["yaxis"]["title"]["text"]} == {
        "alpha",
        "c_gate",
    }
    assert "Table (LaTeX)" in [b.label for b in at.get("download_button")]
    tex = TU.paper_table(at.session_state["_tune_result"][1], "latex")  # the download's payload
    assert "\\toprule" in tex and "test seed 1 x" in tex and tex.isascii()
    tuned = at.session_state["_tune_result"][1].tuned
    at.button(key="tn_compare").click().run()
    assert not at.exception
    # Compare opens with the tuned parameters in its widgets (and so in its URL)
    assert at.session_state["flt"] == ["kf", "huber-kf", "chi2-kf"]
    assert at.session_state["fp.huber-kf.gamma"] == tuned["huber-kf"]["gamma"]


def test_tune_page_refuses_equal_seeds(open_page):
    at = open_page(PAGE, **Q, seed="5", tn_train_seed="5")
    assert not at.exception
    assert any("disjoint" in e.value for e in at.error)
