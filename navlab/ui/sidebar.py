"""The sidebar every run page shares: the experiment's widgets, the configuration upload, the
notices of a link's unused values and of filters left out; the experiment carried to the next
page.

It sits above :mod:`navlab.ui.widgets` (the widgets), :mod:`navlab.ui.frame` (the page menu) and
:mod:`navlab.ui.share` (the upload), which know nothing of it.
"""

from __future__ import annotations

import contextlib
from urllib.parse import parse_qs, urlencode

import streamlit as st

from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec, Plan
from navlab.ui.frame import arrived_from_another_page, fill_nav
from navlab.ui.share import UPLOAD_MSG_KEY, config_upload
from navlab.ui.widgets import (
    CARRY_KEY,
    CARRY_SPEC_KEY,
    PageDefaults,
    experiment_config,
    is_experiment_key,
    link_notice,
    link_query,
    spec_query,
    spec_to_state,
    url_problems,
)


def _restore_history_url() -> bool:
    """On a browser Back/Forward onto this page: give the widgets the experiment of the address
    the browser returned to (an address without one: the session's experiment, as a page link
    carries it); True when done (False: not a history step, or Streamlit's internals changed —
    then the page falls back to the session's experiment as before).

    Streamlit 1.67 drops, on a page change, the URL parameters bound on the page left (the run
    pages share their keys), and on a history step it resets every URL-bound widget to the URL
    or, absent there, to its default — so Back to Compare showed the defaults under an address
    holding the experiment. The parameters are put back from the raw query string of this run.
    """
    try:
        from streamlit.runtime.scriptrunner_utils.script_run_context import get_script_run_ctx

        ctx = get_script_run_ctx()
        if ctx is None or not ctx.is_history_navigation:
            return False
        q = parse_qs(ctx.query_string, keep_blank_values=True)
        if not any(is_experiment_key(k) for k in q):
            carry = st.session_state.get(CARRY_KEY) or {}
            q |= {k: v if isinstance(v, list) else [v] for k, v in carry.items()}
        query = urlencode(q, doseq=True)
        with ctx.session_state.query_params() as qp:
            qp.populate_from_query_string(query)  # unfiltered: the address as shown
            qp.set_initial_query_params(query)  # what the widgets are seeded from
            qp._send_query_param_msg()  # the filtered address went to the browser: put it back
    except (AttributeError, TypeError):
        return False
    return True


def sidebar_experiment(defaults: PageDefaults, page: str, header: str = "Experiment") -> Plan:
    """The sidebar every run page shares: experiment widgets, config upload, skipped filters.

    Returns the experiment planned (validated) once: ``.spec`` is the spec, and the plan itself
    is what :func:`navlab.ui.runner.run_live` takes, so the Run path does not plan it again.

    Every run page passes the same :class:`PageDefaults` (so a link is the same experiment on
    every page). Link values the widgets reject are named in a notice; the page links (drawn by
    :func:`navlab.ui.frame.frame`) carry this experiment to the next page. Stops the page with the
    message when the configuration is invalid.
    """
    carried = st.session_state.get(CARRY_SPEC_KEY)
    if arrived_from_another_page() and not _restore_history_url() and carried:
        # Streamlit drops a link's parameters that are bound to the previous page's widgets on a
        # page change (1.67: populate_from_query_string keeps only the new page's bindings), so
        # the experiment the link carried is written into the widgets from the session instead
        with contextlib.suppress(NavlabError):  # a registry changed under the session: defaults
            spec_to_state(ExperimentSpec.from_json(carried))
            # ... and into the address bar (the old page's bindings are gone, so it may be set),
            # in one URL change: one browser-history entry, not one per parameter (Back then
            # stepped through half-restored experiments)
            with contextlib.suppress(st.errors.StreamlitAPIException):
                st.query_params.update(st.session_state.get(CARRY_KEY) or {})
    problems = url_problems(link_query())
    with st.sidebar:
        st.header(header)
    cfg = experiment_config(defaults)
    # open while it has an upload's message to show (the widgets above it may have changed with
    # the upload, and a changed sidebar redraws the expander closed)
    with st.sidebar.expander("Load / save configuration", expanded=UPLOAD_MSG_KEY in st.session_state):
        config_upload(key=f"up_cfg_{page}")
    if cfg.plan is not None:
        st.session_state[CARRY_KEY] = spec_query(cfg.plan)
        st.session_state[CARRY_SPEC_KEY] = cfg.spec.to_json()
    fill_nav()
    link_notice(page, cfg.spec, problems)
    for key, why in cfg.skipped.items():
        st.warning(f"`{key}` is left out: it {why}.")
    if cfg.error or cfg.plan is None:
        st.error(cfg.error)
        st.stop()
    return cfg.plan
