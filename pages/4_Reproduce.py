"""Reproduce: the papers' tables and curves beside navlab's numbers."""

import time

import streamlit as st

from navlab.errors import NavlabError
from navlab.reproduce import REPRODUCTIONS
from navlab.ui import reproduce as ui
from navlab.ui.frame import frame

frame(
    "Reproduce the papers",
    ":material/article:",
    "Each reproduction runs a paper's experiment with navlab and lays the paper's numbers beside "
    "navlab's: the relative difference, and a note on why they differ (a reconstruction, an "
    "undefined metric, a typo in the paper). The URL keeps the selection.",
)

SMALL_RUNS = 10  # default Monte Carlo size in the browser; the paper's count is one tick away
# page-specific widget keys (session_state is shared with the other pages' flt/runs/seed)
for k, v in {"rep_seed": 1, "rep_runs": SMALL_RUNS, "rep_full": False}.items():
    st.session_state.setdefault(k, v)

keys = sorted(REPRODUCTIONS)
if not keys:
    st.info(
        "No paper reproductions are registered yet. A reproduction is one module in "
        "`navlab/reproduce/` that calls `register(Reproduction(...))`; it appears here by itself."
    )
    st.stop()

if st.session_state.get("rep") not in keys:
    st.session_state["rep"] = keys[0]
key = st.selectbox("Reproduction", keys, key="rep", bind="query-params")
rep = REPRODUCTIONS[key]
st.markdown(f"**{rep.title}**  \n{rep.paper}")

n_paper = ui.paper_runs(rep)
c1, c2, c3 = st.columns([2, 1, 1])
full = c1.checkbox(
    f"Use the paper's Monte Carlo count ({n_paper} runs)" if n_paper else "Use the paper's Monte Carlo count",
    key="rep_full",
    bind="query-params",
    help="Slower; the small default is enough to see the picture.",
)
runs = c2.number_input(
    "Monte Carlo runs",
    1,
    5000,
    step=1,
    key="rep_runs",
    bind="query-params",
    disabled=full,
)
seed = c3.number_input("Seed", 0, 2**31 - 1, step=1, key="rep_seed", bind="query-params")
config = (key, None if full else int(runs), int(seed))

done = st.session_state.setdefault("repro_done", set())
if ui.is_cached(*config):  # computed before on this server (e.g. by whoever shared the link)
    done.add(config)
else:  # never run, or evicted from the bounded cache: ask for Run rather than block silently
    done.discard(config)
if st.button("Run", type="primary", icon=":material/play_arrow:"):
    label = f"{key}: {'the paper’s count' if full else f'{int(runs)} runs'}, seed {int(seed)}"
    with st.status(f"Running {label} …", expanded=True) as status:
        t0 = time.perf_counter()
        progress = None
        if ui.accepts(rep.run, "on_progress"):
            bar = st.progress(0.0, text="starting")

            def progress(d: int, n: int) -> None:
                bar.progress(min(1.0, d / max(n, 1)), text=f"{d}/{n} runs")
        else:
            st.write("This reproduction reports no progress; the status turns green when done.")
        try:
            ui.cached_run(*config, on_progress=progress)
        except NavlabError as exc:
            status.update(label=f"{label}: {exc}", state="error")
            st.error(str(exc))
        except Exception as exc:  # a broken reproduction must not take the page down
            status.update(label=f"{label} failed", state="error")
            st.error(f"The reproduction '{key}' failed: {type(exc).__name__}: {exc}")
        else:
            done.add(config)
            status.update(
                label=f"{label}: done in {time.perf_counter() - t0:.1f} s",
                state="complete",
                expanded=False,
            )

if config not in done:
    st.info("Press **Run** to compute this configuration (a repeated run comes from the cache).")
    st.stop()

table, curves = ui.cached_run(*config)
diff = ui.differences(table)
counts = diff["verdict"].value_counts()
m1, m2, m3, m4 = st.columns(4)
m1.metric("numbers the paper gives", len(diff))
m2.metric("close (≤ 10 %)", int(counts.get("close", 0)))
m3.metric("differ (10–25 %)", int(counts.get("differs", 0)))
m4.metric("far (> 25 %)", int(counts.get("far", 0)))

st.subheader("Paper vs navlab")
if diff.empty:
    st.info("This reproduction reports no paper numbers (navlab's values only).")
else:
    st.caption("Largest disagreement first; the note says why navlab and the paper differ.")
    show = diff[
        ["experiment", "filter", "metric", "paper", "value", "rel_diff", "verdict", "unit", "note"]
    ].rename(columns={"value": "navlab"})
    st.dataframe(
        show.style.format({"paper": "{:.4g}", "navlab": "{:.4g}", "rel_diff": "{:+.1%}"}, na_rep="—")
        .map(
            lambda v: {
                "close": "background-color: #d9f2d9",
                "differs": "background-color: #fff1c2",
                "far": "background-color: #f8d0d0",
            }.get(v, ""),
            subset=["verdict"],
        )
        .map(lambda v: "font-weight: 600", subset=["paper", "navlab"]),
        hide_index=True,
        width="stretch",
        column_config={"note": st.column_config.TextColumn("why they differ", width="large")},
    )
    st.plotly_chart(
        ui.reldiff_figure(table),
        width="stretch",
        config=ui.CONFIG,
        alt="Relative difference navlab vs paper per reported number",
    )
    groups = {f"{e} · {m}": (e, m) for e, m in ui.paper_groups(table)}
    g = groups[st.selectbox("Bar chart of", list(groups), key="rep_bar")]
    st.plotly_chart(
        ui.bar_figure(table, *g), width="stretch", config=ui.CONFIG, alt=f"Paper vs navlab, {g[0]} {g[1]}"
    )

if curves:
    st.subheader("Curves")
    tabs = st.tabs(list(curves))
    for tab, (name, df) in zip(tabs, curves.items(), strict=True):
        with tab:
            measure, cols = None, None
            groups = ui.wide_groups(df)
            if ui.is_long(df):
                measure = st.selectbox("Quantity", ui.curve_measures(df), key=f"curve_{name}")
            elif groups:
                measure = st.selectbox("Quantity", list(groups), key=f"curve_{name}")
                cols = groups[measure]
            st.plotly_chart(
                ui.curve_figure(df, name, measure, cols),
                width="stretch",
                config=ui.CONFIG,
                alt=f"Curves from {name}",
            )
            st.download_button(
                f"Download {name}",
                df.to_csv(index=False).encode(),
                file_name=name.replace("/", "_"),
                mime="text/csv",
                on_click="ignore",
                key=f"dl_{name}",
            )

st.subheader("Full table")
st.dataframe(ui.style_table(table), hide_index=True, width="stretch")
runs_txt = "paper" if config[1] is None else f"{config[1]}runs"
st.download_button(
    "Download the table (CSV)",
    table.to_csv(index=False).encode(),
    file_name=f"navlab-reproduce-{key}-{runs_txt}-seed{config[2]}.csv",
    mime="text/csv",
    on_click="ignore",
    type="primary",
)
