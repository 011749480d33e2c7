"""Sweep: one or two parameters over a range × the chosen filters → metric curves and heat maps."""

import json

import streamlit as st

from navlab.errors import NavlabError
from navlab.ui import figures as F
from navlab.ui import sweep as U
from navlab.ui.frame import frame, plural
from navlab.ui.share import config_download, csv_download, text_download
from navlab.ui.sidebar import sidebar_experiment
from navlab.ui.views import chart
from navlab.ui.widgets import BIND, PageDefaults

PAGE, RESULT_KEY = "sweep", "_sweep_result"

frame(
    "Sweep a parameter",
    "🎚️",
    "Vary one parameter — contamination ratio, outlier scale, noise level, a filter's tuning "
    "constant — or two at once, over a range, and compare every chosen filter at each value.",
    experiment=True,
)

spec = sidebar_experiment(PageDefaults(), "sweep", header="Base experiment").spec

params = {s.id: s for s in U.sweepables(spec)}
if not params:
    st.info("This configuration has no numeric parameter to sweep.")
    st.stop()
ids = list(params)


def axis_controls(tag: str, pid_key: str, first: str, n_default: int, exclude: str | None = None):
    """Parameter, from, to, points, log spacing → (Sweepable, values) or (Sweepable, None)."""
    options = [i for i in ids if i != exclude]
    c1, c2, c3, c4, c5 = st.columns([3, 1, 1, 1, 1])
    pid = c1.selectbox(
        "Parameter" if tag == "sw" else "Second parameter",
        options,
        index=options.index(first) if first in options else 0,
        key=pid_key,
        bind=BIND,
        # no format_func: a bound selectbox puts the formatted option in the URL; the words are
        # in the caption below and on the chart axes
        help="kind.owner.name: ol = outlier model, ns = noise schedule, sc = scenario, fp = filter",
    )
    s = params[pid]
    lo0, hi0 = U.default_range(s)
    num = {"min_value": s.lo, "max_value": s.hi, "format": "%g", "bind": BIND}
    if s.integer:
        num = {
            "min_value": None if s.lo is None else int(s.lo),
            "max_value": None if s.hi is None else int(s.hi),
            "step": 1,
            "bind": BIND,
        }
        lo0, hi0 = int(lo0), int(hi0)
    lo = c2.number_input("from", value=lo0, key=f"{tag}.{pid}.lo", **num)
    hi = c3.number_input("to", value=hi0, key=f"{tag}.{pid}.hi", **num)
    nkey, logkey = ("swn", "swlog") if tag == "sw" else ("sw2n", "sw2log")
    n = int(
        c4.number_input(
            "points", min_value=2, max_value=U.MAX_POINTS, value=n_default, step=1, key=nkey, bind=BIND
        )
    )
    log = c5.checkbox("log spacing", key=logkey, bind=BIND)
    st.caption(f"**{s.label}** — `{s.cli}` on the command line (default {s.default:g})")
    try:
        return s, U.grid(s, float(lo), float(hi), n, log), bool(log)
    except NavlabError as exc:
        st.error(str(exc))
        return s, None, bool(log)


# the outlier ratio, else the noise schedule's multiplier (the default experiment has no outliers)
first = next((i for i in ids if i.endswith(".contamination")), None)
first = first or next((i for i in ids if i.startswith("ns.") and i.endswith(".factor")), ids[0])
s1, v1, log1 = axis_controls("sw", "swp", first, 6)
two = st.toggle(
    "Second parameter (2-D sweep: a heat map per filter)",
    key="sw2",
    bind=BIND,
    help="every combination of the two parameters' values is one experiment",
)
s2 = v2 = None
if two:
    second = next((i for i in ids if i != s1.id and i.startswith("fp.")), next(i for i in ids if i != s1.id))
    s2, v2, _ = axis_controls("sw2", "swp2", second, 4, exclude=s1.id)
if v1 is None or (two and v2 is None):
    st.stop()

axes = [U.Axis(s1, tuple(v1))] + ([U.Axis(s2, tuple(v2))] if two else [])
try:
    sw = U.make_sweep(spec, axes)
except NavlabError as exc:
    st.error(str(exc))
    st.stop()
sweep_id = json.dumps(
    {"spec": spec.to_dict(), "axes": [[a.param.id, list(a.values)] for a in axes]}, sort_keys=True
)

b1, b2, b3, b4 = st.columns([1, 1, 1, 3])
if b1.button("Run sweep", type="primary", key="run_sweep"):
    U.request(PAGE, sweep_id)
    st.session_state.pop(RESULT_KEY, None)
config_download(spec, key="dl_cfg_sweep", container=b3)
n_tasks = len({t.key for t in sw.all_tasks()})
b4.caption(
    f"{len(sw.points)} points × {plural(len(spec.filters), 'filter')}, {spec.runs} runs each: "
    f"{plural(n_tasks, 'task')}, "
    f"run {U.where_text()}; finished tasks are kept on the server, so a repeated or resumed sweep "
    "computes only what is missing"
)

progress_box = st.container()  # the progress under Run sweep, not below the charts
controls = st.container()
lines_ph, heat_ph = st.empty(), st.empty()

out = None
hit = st.session_state.get(RESULT_KEY)
if hit and hit[0] == sweep_id:
    out = hit[1]
elif U.requested(PAGE, sweep_id):

    def work(**kw):
        return U.run_sweep(sw, **kw)

    with progress_box:
        out = U.run_job(PAGE, b2, work)
else:  # what the store already holds of this sweep (nothing is computed)
    out = U.run_sweep(sw, store=U.app_store(), should_stop=U.stored_only)
    if out.done_points == 0:
        if out.tasks_done:
            lines_ph.info(
                f"{out.tasks_done} of {out.tasks_total} tasks finished and kept (no point complete "
                "yet): press **Run sweep** to resume."
            )
        else:
            lines_ph.info("Press **Run sweep** to compute the grid.")
        out = None
if out is not None:
    if out.complete:
        st.session_state[RESULT_KEY] = (sweep_id, out)
        st.caption(f"{out.done_points} points · {out.cached} of {out.tasks_total} tasks from the store")
    else:
        st.info(
            f"{out.done_points} of {out.total_points} points finished ({out.tasks_done} of "
            f"{out.tasks_total} tasks kept): press **Run sweep** to resume."
        )

if out is not None and len(out.rows):
    df = out.rows
    metrics = [m for m in dict.fromkeys(df.metric) if m.startswith("rmse_")]
    metrics += [
        m
        for m in (
            "mean_rmse_pos",
            "anees",
            "anis",
            "rhat_err_pct",
            "detected_pct",
            "false_alarm_pct",
            "diverged",
        )
        if m in set(df.metric)
    ]
    units = dict(zip(df.metric, df.unit, strict=False))
    m1, m2, m3, m4 = controls.columns([2, 1, 1, 2])
    metric = m1.selectbox(
        "Metric", metrics, key="sw_v_metric", format_func=lambda m: F.metric_title(m, units.get(m, ""))
    )
    d = df[df.metric == metric]
    ylab = F.metric_title(metric, units.get(metric, ""))
    if not two:
        log_y = m2.toggle("log y", key="sw_v_logy")
        log_x = m3.toggle("log x", value=bool(log1), key="sw_v_logx")
        d1 = d.rename(columns={"value": "metric_value", "param_value": "value"})
        chart(lines_ph, F.sweep_lines(d1, s1.label, ylab, log_x=log_x, log_y=log_y), "metric vs parameter")
        chart(heat_ph, F.sweep_heatmap(d1, s1.label, ylab), "heat map of the metric")
    else:
        labels = list(dict.fromkeys(d.label))
        who = m4.selectbox("Filter", labels, key="sw_v_filter")
        dd = d[d.label == who]
        title = f"{ylab} of {who} (hover: 95 % interval)"
        chart(lines_ph, F.sweep_heatmap_2d(dd, s1.label, s2.label, ylab, title), "2-D heat map")
    diverged = df[(df.metric == "diverged") & (df.value > 0)]
    if len(diverged):
        where = [
            f"{r.label} at {r.param_value:g}"
            + (f" × {r.param2_value:g}" if two else "")
            + f": {int(r.value)}"
            for r in diverged.itertuples()
        ]
        st.warning("Diverged runs (excluded from the metrics): " + "; ".join(where))
    e1, e2, _ = st.columns([1, 1, 3])
    csv_download(df, "Sweep results (CSV)", "navlab-sweep.csv", "dl_sweep", container=e1)
    text_download(
        lambda: U.paper_tables(out, sw, metric, "latex"),
        "Table (LaTeX)",
        "navlab-sweep.tex",
        "dl_sweep_tex",
        "application/x-tex",
        "the chosen metric at every point for a paper: booktabs, values with their 95 % intervals, "
        "a caption naming the runs, seed and interval method",
        container=e2,
    )
