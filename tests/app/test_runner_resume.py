"""run_live when the session holds a complete result that was never stored (a click during the
last batch: the rerun is raised after the batch, before the store)."""

from __future__ import annotations

from apphelpers import TIMEOUT, assert_clean
from streamlit.testing.v1 import AppTest


def _script():
    import streamlit as st

    from navlab.experiment import ExperimentSpec, run_experiment
    from navlab.ui import runner

    spec = ExperimentSpec(runs=3, epochs=12, seed=912_345)
    if "seeded" not in st.session_state:
        st.session_state["seeded"] = True
        runner.result_store().clear()
        st.session_state[runner.PARTIAL_KEY] = {"p": (spec.to_json(), run_experiment(spec))}
        runner.request_run("p", spec)
    res = runner.run_live(spec, "p", lambda r: st.caption(f"rendered {r.done_runs}"))
    st.markdown(f"runs {res.done_runs} stored {runner.cached_results(spec) is not None}")
    st.markdown(f"partial {'p' in st.session_state[runner.PARTIAL_KEY]}")
    st.markdown(f"pending {runner.run_requested('p', spec)}")


def test_a_complete_partial_is_stored_not_an_assertion():
    at = AppTest.from_function(_script, default_timeout=TIMEOUT)
    at.run()
    assert_clean(at)
    text = [m.value for m in at.markdown]
    assert text == ["runs 3 stored True", "partial False", "pending False"]
    assert [c.value for c in at.caption] == ["rendered 3"]


def _script_click_in_last_batch():
    import streamlit as st

    from navlab.experiment import ExperimentSpec
    from navlab.ui import runner

    spec = ExperimentSpec(runs=3, epochs=12, seed=912_346)
    if "seeded" not in st.session_state:
        st.session_state["seeded"] = True
        runner.result_store().clear()
        runner.request_run("p", spec)
    else:  # the rerun the click asked for: the finished run was stored before it
        st.markdown(f"stored before {runner.cached_results(spec) is not None}")

    def render(res):
        if not st.session_state.get("clicked"):
            st.session_state["clicked"] = True
            st.rerun()  # as a click during the batch: raised at the next yield point

    res = runner.run_live(spec, "p", render)
    st.markdown(f"runs {res.done_runs}")


def test_a_click_during_the_last_batch_stores_the_finished_run():
    at = AppTest.from_function(_script_click_in_last_batch, default_timeout=TIMEOUT)
    at.run()
    assert_clean(at)
    assert [m.value for m in at.markdown] == ["stored before True", "runs 3"]
