"""Sweep: one parameter over a range × the chosen filters → RMSE curves and a heat map."""

import json

import streamlit as st

from navlab.errors import NavlabError
from navlab.ui import figures as F
from navlab.ui.frame import frame
from navlab.ui.runner import metrics_cached, show_error
from navlab.ui.share import config_download, csv_download
from navlab.ui.sweep import MAX_POINTS, default_range, grid, run_sweep, sweepables
from navlab.ui.views import chart
from navlab.ui.widgets import BIND, PageDefaults, sidebar_experiment

RESULT_KEY, PENDING_KEY = "_sweep_result", "_sweep_pending"

frame(
    "Sweep a parameter",
    "🎚️",
    "Vary one parameter — contamination ratio, outlier scale, noise level, a filter's tuning "
    "constant — over a range and compare every chosen filter at each value.",
)

spec = sidebar_experiment(PageDefaults(runs=30), "sweep", header="Base experiment")

params = {s.id: s for s in sweepables(spec)}
if not params:
    st.info("This configuration has no numeric parameter to sweep.")
    st.stop()
ids = list(params)
first = next((i for i in ids if i.endswith(".contamination")), ids[0])
c1, c2, c3, c4, c5 = st.columns([3, 1, 1, 1, 1])
pid = c1.selectbox(
    "Parameter",
    ids,
    index=ids.index(first),
    key="swp",
    bind=BIND,
    help="kind.owner.name: ol = outlier model, ns = noise schedule, sc = scenario, fp = filter parameter",
)
s = params[pid]
lo0, hi0 = default_range(s)
num = {"min_value": s.lo, "max_value": s.hi, "format": "%g", "bind": BIND}
if s.integer:
    num = {
        "min_value": None if s.lo is None else int(s.lo),
        "max_value": None if s.hi is None else int(s.hi),
        "step": 1,
        "bind": BIND,
    }
    lo0, hi0 = int(lo0), int(hi0)
lo = c2.number_input("from", value=lo0, key=f"sw.{pid}.lo", **num)
hi = c3.number_input("to", value=hi0, key=f"sw.{pid}.hi", **num)
n = int(c4.number_input("points", min_value=2, max_value=MAX_POINTS, value=6, step=1, key="swn", bind=BIND))
log = c5.checkbox("log spacing", key="swlog", bind=BIND)
st.caption(f"**{s.label}** — {s.help or 'no description'} (default {s.default:g})")

try:
    values = grid(s, float(lo), float(hi), n, log)
except NavlabError as exc:
    st.error(str(exc))
    st.stop()
sweep_id = json.dumps({"spec": spec.to_dict(), "param": pid, "values": values.tolist()}, sort_keys=True)

b1, b2, b3 = st.columns([1, 1, 4])
if b1.button("Run sweep", type="primary", key="run_sweep"):
    st.session_state[PENDING_KEY] = sweep_id
config_download(spec, key="dl_cfg_sweep", container=b2)
b3.caption(
    f"{len(values)} values × {len(spec.filters)} filters × {spec.runs} runs: "
    + ", ".join(f"{v:g}" for v in values)
)

controls = st.container()
lines_ph, heat_ph = st.empty(), st.empty()

df = None
hit = st.session_state.get(RESULT_KEY)
if hit and hit[0] == sweep_id:
    df = hit[1]
elif st.session_state.get(PENDING_KEY) == sweep_id:
    bar = st.progress(0.0, text="sweeping…")

    def on_point(i, total, table):
        bar.progress(i / total, text=f"{i}/{total} values done")
        rm = table[table.metric == table.metric.iloc[0]]
        chart(lines_ph, F.sweep_lines(rm, pid, table.metric.iloc[0]), "sweep so far")

    try:
        df = run_sweep(spec, s, values, metrics_cached, on_point)
    except Exception as exc:  # shown as a message, never a traceback
        show_error(exc)
    finally:
        st.session_state.pop(PENDING_KEY, None)
    if df is not None:
        st.session_state[RESULT_KEY] = (sweep_id, df)
        bar.progress(1.0, text=f"done: {len(values)} values")
else:
    lines_ph.info("Press **Run sweep** to compute the grid.")

if df is not None:
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
    m1, m2, m3 = controls.columns([2, 1, 1])
    units = dict(zip(df.metric, df.unit, strict=False))
    metric = m1.selectbox(
        "Metric", metrics, key="sw_v_metric", format_func=lambda m: F.metric_title(m, units.get(m, ""))
    )
    log_y = m2.toggle("log y", key="sw_v_logy")
    log_x = m3.toggle("log x", value=bool(log), key="sw_v_logx")
    d = df[df.metric == metric]
    ylab = F.metric_title(metric, units.get(metric, ""))
    chart(lines_ph, F.sweep_lines(d, pid, ylab, log_x=log_x, log_y=log_y), "metric vs parameter")
    chart(heat_ph, F.sweep_heatmap(d, pid, ylab), "heat map of the metric")
    diverged = df[(df.metric == "diverged") & (df.metric_value > 0)]
    if len(diverged):
        st.warning(
            "Diverged runs (excluded from the metrics): "
            + "; ".join(f"{r.label} at {r.value:g}: {int(r.metric_value)}" for r in diverged.itertuples())
        )
    csv_download(df, "Sweep results (CSV)", "navlab-sweep.csv", "dl_sweep")
