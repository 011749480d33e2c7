"""Reproduce: every claim of a paper judged over many Monte Carlo seeds, with a verdict."""

import json

import streamlit as st

from navlab.params import SEED_MAX
from navlab.reproduce import REPRODUCTIONS
from navlab.reproduce.report import RULES_FOOT, latex, rules_text
from navlab.ui import reproduce as ui
from navlab.ui import sweep as U
from navlab.ui.frame import frame
from navlab.ui.share import csv_download, text_download
from navlab.ui.views import chart

PAGE = "reproduce"

frame(
    "Reproduce the papers",
    ":material/article:",
    "Each reproduction runs a paper's experiment with navlab on many Monte Carlo sets ('seeds') and "
    "turns every claim of the paper — a number, a ranking, a margin — into one verdict: reproduced, "
    "contradicted, inconclusive, setup-dependent (another documented setting gives the other answer) "
    "or not testable. The URL keeps the selection.",
)

keys = sorted(REPRODUCTIONS)
if not keys:
    st.info("No paper reproductions are registered yet (a module in navlab/reproduce/ that calls register).")
    st.stop()
c0, c1, c2, c3 = st.columns([3, 1, 1, 1])
# the defaults as the widgets' own (not set in the session first): a link's value equal to a
# widget's default would otherwise be dropped from the URL and lose to the session's value
key = c0.selectbox(
    "Reproduction", keys, index=keys.index(ui.default_key(keys)), key="rep", bind="query-params"
)
rep = REPRODUCTIONS[key]
seeds = int(
    c1.number_input(
        "Seeds",
        1,
        100,
        value=ui.APP_SEEDS,
        step=1,
        key="rep_seeds",
        bind="query-params",
        help=f"Monte Carlo sets of the paper's run count; the CLI uses 20 "
        f"(the app starts with {ui.APP_SEEDS} for a first look in seconds)",
    )
)
runs = int(
    c2.number_input(
        "Runs per seed",
        1,
        5000,
        value=rep.default_runs,
        step=1,
        key=f"rep_runs_{key}",
        bind="query-params",
        help=f"the paper's count: {rep.default_runs}",
    )
)
seed = int(c3.number_input("Base seed", 0, SEED_MAX, value=1, step=1, key="rep_seed", bind="query-params"))
st.markdown(f"**{rep.title}**  \n{rep.paper}")
st.caption(ui.seeds_note(key, seeds))

config = (key, runs, seeds, seed)
job = json.dumps(config)
b1, b2, b3 = st.columns([1, 1, 6])
if b1.button("Run", type="primary", icon=":material/play_arrow:", key="rep_run"):
    U.request(PAGE, job)
b3.caption("Finished seed blocks are kept on the server: a stopped or repeated reproduction resumes.")

progress, board, stop = st.container(), st.empty(), b2.empty()
if U.requested(PAGE, job):
    with progress:  # the progress bar under Run, the verdicts below it
        out = ui.run_live(PAGE, config, stop, lambda o: ui.show_verdicts(board, o))
    stop.empty()
else:
    out = ui.stored_outcome(config)
    if out is not None:
        ui.show_verdicts(board, out)
if out is None:
    ui.show_claims(board, rep)
    st.stop()
if not out.complete:
    st.info(f"{out.seeds} of {seeds} seeds judged and kept: press **Run** to resume.")

with st.expander("Why each verdict (notes per claim) and the rules"):
    for i, note in enumerate(out.verdicts["note"], 1):
        if note:
            st.markdown(f"{i}. {note}")
    st.markdown("**Verdict kinds** (docs/STATISTICS.md §4):\n" + rules_text())
    st.caption(RULES_FOOT)
v1, v2, _ = st.columns([1, 1, 3])
csv_download(
    out.verdicts, "Verdicts (CSV)", f"navlab-reproduce-{key}-verdicts.csv", "dl_verdicts", container=v1
)
text_download(
    lambda: latex(out),
    "Verdicts (LaTeX)",
    f"navlab-reproduce-{key}.tex",
    "dl_verdicts_tex",
    "application/x-tex",
    "the verdict table for a paper (booktabs; caption with seeds, runs and the interval method)",
    container=v2,
)

readings = st.expander(
    "Detailed readings: every quantity of every filter, pooled over the judged seeds",
    key="rep_readings",
    on_change="rerun",
)
if readings.open:  # a bootstrap per quantity and filter: computed when opened
    readings.dataframe(ui.readings_table(out), hide_index=True, width="stretch")
    csv_download(
        out.readings, "Readings (CSV)", f"navlab-reproduce-{key}-readings.csv", "dl_readings", readings
    )

if out.curves:
    st.subheader("Curves")
    names = list(out.curves)
    tabs = st.tabs([ui.curve_label(out, n) for n in names])
    for tab, name in zip(tabs, names, strict=True):
        with tab:
            chart(st, ui.curve_figure(out, name), f"Curves {name}", name=name)
            csv_download(out.curves[name], f"Download {name}", name, f"dl_{name}")
