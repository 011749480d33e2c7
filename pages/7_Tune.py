"""Tune: every chosen filter tuned on the same budget on training seeds, judged on test seeds."""

import json

import streamlit as st

from navlab import tune as TU
from navlab.errors import NavlabError
from navlab.params import SEED_MAX
from navlab.tasks import StoppedError
from navlab.ui import figures as F
from navlab.ui import sweep as U
from navlab.ui.frame import frame
from navlab.ui.share import csv_download, text_download
from navlab.ui.sidebar import sidebar_experiment
from navlab.ui.views import chart
from navlab.ui.widgets import BIND, PageDefaults, spec_to_state

PAGE, RESULT_KEY, GOTO_KEY = "tune", "_tune_result", "_tune_goto_compare"

if st.session_state.pop(GOTO_KEY, False):
    # the widgets hold the tuned configuration (written by the button's callback); an empty
    # query string lets Compare's widgets take it from there (switch_page would otherwise try
    # to clear the parameters bound to this page's widgets, which Streamlit refuses)
    st.switch_page("pages/1_Compare.py", query_params={})

frame(
    "Tune filters fairly",
    "🎛️",
    "Is a filter better, or just better tuned? Every chosen filter's hyper-parameters are tuned "
    "on the same budget on training seeds; default and tuned filters are then compared on other "
    "(test) seeds with paired statistics.",
    experiment=True,
)

spec = sidebar_experiment(PageDefaults(), "tune", header="Experiment (test runs)").spec

c1, c2, c3, c4 = st.columns([1, 1, 2, 1])
budget = int(
    c1.number_input(
        "Budget",
        min_value=2,
        max_value=64,
        value=8,
        step=1,
        key="tn_budget",
        bind=BIND,
        help="candidates per filter: the default + budget − 1 Sobol points, then successive halving",
    )
)
train_runs = int(
    c2.number_input(
        "Training runs",
        min_value=1,
        max_value=1000,
        value=min(16, TU.default_train_runs(spec)),
        step=2,
        key="tn_train_runs",
        bind=BIND,
        help="runs per candidate on the last successive-halving rung (earlier rungs: fewer)",
    )
)
head = TU.parse_objective(None, spec).metric
objectives = [head, f"consistent_{head}", *TU.truth_free_objectives(spec)]
objective = c3.selectbox(
    "Objective",
    objectives,
    key="tn_obj",
    bind=BIND,
    help="minimised on the training seeds; consistent_…: × a penalty when the ANEES leaves its χ² "
    "band; nlpd (filters that state their predictive density): needs no truth",
)
train_seed = int(
    c4.number_input(
        "Training seed",
        min_value=0,
        max_value=SEED_MAX,
        value=spec.seed + 1,
        step=1,
        key="tn_train_seed",
        bind=BIND,
        help="the test seed is the sidebar's seed; the two must differ",
    )
)
try:
    st_ = TU.setup(spec, budget=budget, objective=objective, train_seeds=[train_seed], train_runs=train_runs)
except NavlabError as exc:
    st.error(str(exc))
    st.stop()
st.caption(
    " ".join(st_.describe())
    + " Tunable: "
    + (
        "; ".join(
            f"**{k}** "
            + ", ".join(
                f"{d.name} ∈ [{d.lo:g}, {d.hi:g}]" + (" (log)" if d.scale != "linear" else "") for d in ds
            )
            for k, ds in st_.dims.items()
            if ds
        )
        or "none of the chosen filters has a tunable parameter"
    )
    + "."
)
tune_id = json.dumps(
    {"spec": spec.to_dict(), "budget": budget, "obj": objective, "train": train_seed, "runs": train_runs},
    sort_keys=True,
)

b1, b2, b3 = st.columns([1, 1, 4])
if b1.button("Run tuning", type="primary", key="run_tune"):
    U.request(PAGE, tune_id)
b3.caption(
    f"at most {TU.count_tasks(st_)} tasks, run {U.where_text()}; finished tasks are kept on the server"
)

r = None
hit = st.session_state.get(RESULT_KEY)
if hit and hit[0] == tune_id:
    r = hit[1]
elif U.requested(PAGE, tune_id):

    def work(**kw):
        try:
            return TU.tune(st_, **kw)
        except StoppedError as exc:
            st.info(f"Stopped: {exc}")
            return None

    r = U.run_job(PAGE, b2, work)
else:  # a tuning whose tasks are all in the store shows at once (nothing is computed)
    try:
        r = TU.tune(st_, store=U.app_store(), should_stop=U.stored_only)
    except StoppedError:
        st.info("Press **Run tuning** to tune the chosen filters (finished tasks are reused).")
    except NavlabError as exc:
        st.error(str(exc))
if r is not None:
    st.session_state[RESULT_KEY] = (tune_id, r)

if r is not None:
    rep = TU.report(r)
    st.markdown("##### Default against tuned, on the test seeds")
    st.table(rep.cells)  # wraps: the paired verdicts stay on screen
    st.caption("  \n".join(rep.notes))

    def open_compare(res=r) -> None:
        spec_to_state(res.tuned_spec())
        st.session_state[GOTO_KEY] = True

    row = st.container(horizontal=True)  # each button as wide as its label (none cut to "JS…")
    row.button(
        "Open Compare with the tuned parameters",
        key="tn_compare",
        on_click=open_compare,
        help="the same experiment on the test seed, every filter with its tuned parameters",
    )
    csv_download(r.rows, "Tuning results (CSV)", "navlab-tune.csv", "dl_tune", container=row)
    row.download_button(
        "Tuned configuration (JSON)",
        r.tuned_spec().to_json(indent=1),
        file_name="navlab-tuned.json",
        mime="application/json",
        key="dl_tuned_cfg",
    )
    text_download(
        lambda: TU.paper_table(r, "latex"),
        "Table (LaTeX)",
        "navlab-tune.tex",
        "dl_tune_tex",
        "application/x-tex",
        "the table above for a paper: booktabs, values with their 95 % intervals, a caption naming "
        "the seeds, runs and interval method (needs \\usepackage{booktabs})",
        container=row,
    )
    st.markdown("##### Objective landscapes (training seeds, first rung: every candidate on the same runs)")
    trials = TU.trials_frame(r)
    tuned_keys = [k for k, ds in st_.dims.items() if ds]
    cols = st.columns(2)
    for i, k in enumerate(tuned_keys):
        names = TU.influential(r, k)
        label = r.test.runs[k + TU.TEST_SUFFIX].label.replace(" (tuned)", "")
        fig = F.tune_landscape(trials[trials["filter"] == k], st_.dims[k], names, r.tuned[k], label)
        chart(cols[i % 2], fig, f"objective landscape of {k}")
