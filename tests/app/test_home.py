from apphelpers import assert_clean


def test_home_renders_papers_and_sources(open_page):
    at = open_page()
    assert_clean(at)
    text = " ".join(m.value for m in at.markdown)
    for word in ("HAKF", "IRAKF", "NNMFUKF", "VB-EKF", "Where to start", "smartLoc", "rtkx"):
        assert word in text or word in " ".join(s.value for s in at.subheader), word
    assert at.title[0].value.startswith("navlab")


def test_home_demo_shows_a_result_figure_in_one_click(open_page):
    at = open_page()
    assert not at.get("plotly_chart")
    at.button(key="home_demo").click().run()
    assert_clean(at)
    import json

    err, rhat = [json.loads(el.proto.spec) for el in at.get("plotly_chart")]
    names = {t.get("name") for t in err["data"]}
    assert {"KF", "Sage–Husa AKF", "AKF (VB)", "HAKF (VB + Huber)", "Oracle KF"} <= names
    # #21: the demo shows R̂ against the true R(t), and says what to look at
    assert "AKF (VB) R̂" in {t.get("name") for t in rhat["data"]}
    assert any(m.value.startswith("**What to look at.** The true σ") for m in at.markdown)


def test_home_lists_the_filters_by_family_with_one_line_each(open_page):
    from navlab.filters import registry

    at = open_page()
    text = " ".join(m.value for m in at.markdown)
    for head in ("**Baselines**", "**Robust**", "**Adaptive**", "**Robust and adaptive**"):
        assert head in text
    for key, cls in registry().items():
        assert f"**{cls.label}** (`{key}`) — {cls.summary}" in text


def test_worker_processes_do_not_run_the_page_again(open_page):
    """Issue 22 item 11: 966 'missing ScriptRunContext' warnings in one short session came from
    worker processes (the embedded Dask cluster's, started by "spawn"), each of which ran the
    current page again in bare mode."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from apphelpers import main_rerun_in_child

    open_page("pages/2_Noise.py")  # Streamlit leaves the page's module as __main__
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        assert pool.submit(main_rerun_in_child).result(timeout=120) is None


def test_home_demo_spans_the_page_above_the_two_columns(open_page):
    """In the narrow right column the demo's R̂ small multiples overlapped their titles and cut
    the link to Compare: the demo now comes first, at full width."""
    at = open_page()
    assert [s.value for s in at.subheader][:2] == ["See it in seconds", "Where to start"]
    assert all("home_demo" not in [b.key for b in c.button] for c in at.columns)
