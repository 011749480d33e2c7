"""Reproduce: every claim of a paper judged over many Monte Carlo seeds, with a verdict."""

import time

import streamlit as st

from navlab.errors import NavlabError
from navlab.params import SEED_MAX
from navlab.reproduce import REPRODUCTIONS
from navlab.reproduce.report import RULES, header
from navlab.ui import reproduce as ui
from navlab.ui.frame import frame
from navlab.ui.runner import show_error
from navlab.ui.views import chart

frame(
    "Reproduce the papers",
    ":material/article:",
    "Each reproduction runs a paper's experiment with navlab on many Monte Carlo sets ('seeds') and "
    "turns every claim of the paper — a number, a ranking, a margin — into one verdict: reproduced, "
    "contradicted or inconclusive. The URL keeps the selection.",
)

keys = sorted(REPRODUCTIONS)
if not keys:
    st.info("No paper reproductions are registered yet (a module in navlab/reproduce/ that calls register).")
    st.stop()
for k, v in {"rep": keys[0], "rep_seeds": ui.APP_SEEDS, "rep_seed": 1}.items():
    st.session_state.setdefault(k, v)
if st.session_state["rep"] not in keys:
    st.session_state["rep"] = keys[0]

c0, c1, c2, c3 = st.columns([3, 1, 1, 1])
key = c0.selectbox("Reproduction", keys, key="rep", bind="query-params")
rep = REPRODUCTIONS[key]
seeds = int(
    c1.number_input(
        "Seeds",
        1,
        100,
        step=1,
        key="rep_seeds",
        bind="query-params",
        help=f"Monte Carlo sets of the paper's run count; the CLI uses 20 "
        f"(the app starts with {ui.APP_SEEDS} for a quick first look)",
    )
)
st.session_state.setdefault(f"rep_runs_{key}", rep.default_runs)
runs = int(
    c2.number_input(
        "Runs per seed",
        1,
        5000,
        step=1,
        key=f"rep_runs_{key}",
        bind="query-params",
        help=f"the paper's count: {rep.default_runs}",
    )
)
seed = int(c3.number_input("Base seed", 0, SEED_MAX, step=1, key="rep_seed", bind="query-params"))
st.markdown(f"**{rep.title}**  \n{rep.paper}")
if seeds < 20:
    st.caption(
        f"{seeds} seeds: a first look. The CLI judges at 20 seeds "
        f"(`python -m navlab reproduce {key}`); verdicts can change with more seeds."
    )

config = (key, runs, seeds, seed)
if st.button("Run", type="primary", icon=":material/play_arrow:", key="rep_run"):
    label = f"{key}: {seeds} seeds × {runs} runs, base seed {seed}"
    with st.status(f"Running {label} …", expanded=True) as status:
        t0 = time.perf_counter()
        bar = st.progress(0.0, text="starting")
        try:
            ui.cached_run(
                *config, on_progress=lambda d, n: bar.progress(min(1.0, d / max(n, 1)), text=f"{d}/{n} runs")
            )
        except NavlabError as exc:
            status.update(label=f"{label}: {exc}", state="error")
            st.error(str(exc))
        except Exception as exc:  # a broken reproduction must not take the page down
            status.update(label=f"{label} failed", state="error")
            show_error(exc)
        else:
            status.update(
                label=f"{label}: done in {time.perf_counter() - t0:.1f} s", state="complete", expanded=False
            )

if not ui.is_cached(*config):
    st.info("Press **Run** to judge the paper's claims (a repeated configuration comes from the cache).")
    st.stop()

o = ui.cached_run(*config)
counts = o.verdicts["verdict"].value_counts()
m1, m2, m3, m4 = st.columns(4)
m1.metric("claims", len(o.verdicts))
m2.metric("reproduced", int(counts.get("reproduced", 0)))
m3.metric("contradicted", int(counts.get("contradicted", 0)))
m4.metric("inconclusive", int(counts.get("inconclusive", 0)))

st.subheader("The paper's claims")
st.caption(header(o).replace("\n", "  \n"))
st.dataframe(
    ui.style_verdicts(o),
    hide_index=True,
    width="stretch",
    column_config={"claim": st.column_config.TextColumn("claim", width="large")},
)
with st.expander("Why each verdict (notes per claim) and the rules"):
    for i, note in enumerate(o.verdicts["note"], 1):
        if note:
            st.markdown(f"{i}. {note}")
    st.caption(RULES)
chart(st, ui.claims_figure(o), "navlab's value relative to the paper's for every number claim", name="claims")
st.download_button(
    "Verdicts (CSV)",
    o.verdicts.to_csv(index=False).encode(),
    file_name=f"navlab-reproduce-{key}-verdicts.csv",
    mime="text/csv",
    on_click="ignore",
)

with st.expander("Detailed readings: every quantity of every filter, pooled over all seeds"):
    st.dataframe(ui.readings_table(o), hide_index=True, width="stretch")
    st.download_button(
        "Readings (CSV)",
        o.readings.to_csv(index=False).encode(),
        file_name=f"navlab-reproduce-{key}-readings.csv",
        mime="text/csv",
        on_click="ignore",
    )

if o.curves:
    st.subheader("Curves")
    names = list(o.curves)
    tabs = st.tabs([n.removeprefix(f"{key}_").removesuffix(".csv") for n in names])
    for tab, name in zip(tabs, names, strict=True):
        with tab:
            chart(st, ui.curve_figure(o, name), f"Curves {name}", name=name)
            st.download_button(
                f"Download {name}",
                o.curves[name].to_csv(index=False).encode(),
                file_name=name,
                mime="text/csv",
                on_click="ignore",
                key=f"dl_{name}",
            )
