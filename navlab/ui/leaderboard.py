"""The Leaderboard page: the last ``navlab bench`` — overall standing, a heat map of every filter's
gap to the floor on every problem (each cell a link to that experiment on Compare), and the
ranked table of a problem.
"""

from __future__ import annotations

import html
import math
from typing import Any
from urllib.parse import urlencode

import numpy as np
import pandas as pd
import streamlit as st

from navlab import bench as BN
from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec
from navlab.stats import sig3
from navlab.tables import cell
from navlab.ui.widgets import spec_query

NO_BENCH = (
    "No bench yet. Run one in a terminal — `navlab bench --suite small` (a few minutes on two "
    "cores; `--scheduler tcp://HOST:8786` sends it to a Dask cluster) — and reload this page. "
    f"It reads `{BN.LAST}` from `NAVLAB_BENCH_DIR` (default ~/.cache/navlab/bench)."
)


def compare_link(problem: dict[str, Any]) -> str | None:
    """The Compare page's URL (relative) of ``problem``'s experiment: every filter with its tuned
    parameters, on the test seed — a run there shows the numbers of the bench's table.
    """
    spec = ExperimentSpec.from_dict(problem["spec"])
    try:
        q = spec_query(spec)
    except NavlabError:  # a filter no longer registered (a plugin removed since the bench)
        return None
    return "Compare?" + urlencode({**q, "go": "1"}, doseq=True)


def _num(v: Any) -> float:
    """A JSON number (null: NaN)."""
    return math.nan if v is None else float(v)


def heat_color(gap: float, top: float) -> str:
    """White at the floor (gap 1) to red at ``top`` (log scale); grey where there is no value."""
    if not np.isfinite(gap):
        return "#eeeeee"
    u = 0.0 if top <= 1 else min(1.0, max(0.0, math.log(max(gap, 1.0)) / math.log(top)))
    g = round(255 - 150 * u)
    return f"rgb(255,{g},{g})"


def heat_map_html(bench: dict[str, Any]) -> str:
    """Filters (in overall order) × problems: each filter's gap to the floor (tuned, test seed) as a
    linked cell; a wide suite scrolls sideways.
    """
    probs = bench["problems"]
    keys: list[str] = []
    labels: dict[str, str] = {}
    for p in probs:
        for r in p["rows"]:
            if r["filter"] not in keys:
                keys.append(r["filter"])
                labels[r["filter"]] = str(r["label"]).replace(" (tuned)", "")
    order = [r["filter"] for r in bench.get("overall", [])]
    keys = [k for k in order if k in keys] + [k for k in keys if k not in order]
    gaps = [r.get("gap") for p in probs for r in p["rows"]]
    fin = [g for g in gaps if g is not None and np.isfinite(g)]
    top = max(fin) if fin else 2.0
    by = [{r["filter"]: r for r in p["rows"]} for p in probs]
    links = [compare_link(p) for p in probs]
    head = "".join(f'<th style="padding:2px 6px">{html.escape(p["name"])}</th>' for p in probs)
    out = [
        '<div style="overflow-x:auto"><table style="border-collapse:collapse;font-size:0.85em">',
        f"<tr><th>filter</th>{head}</tr>",
    ]
    for k in keys:
        tds = []
        for p, rows, link in zip(probs, by, links, strict=True):
            r = rows.get(k)
            g = _num(r.get("gap")) if r is not None else math.nan
            style = f"background:{heat_color(g, top)};padding:2px 6px;text-align:right"
            if r is None or not np.isfinite(g):
                tds.append(f'<td style="{style}">—</td>')
                continue
            txt = f"{sig3(g)}×" + (" ⚠" if r.get("reliable") is False else "")
            rmse = cell(r["value"], _num(r.get("ci_lo")), _num(r.get("ci_hi")))
            tip = html.escape(f"{labels[k]} on {p['name']}: RMSE {rmse} {r['unit']}; {r.get('verdict', '')}")
            inner = f'<a href="{html.escape(link)}" target="_self">{txt}</a>' if link else txt
            tds.append(f'<td style="{style}" title="{tip}">{inner}</td>')
        out.append(f"<tr><td>{html.escape(labels[k])}</td>{''.join(tds)}</tr>")
    out.append("</table></div>")
    return "".join(out)


def overall_table(bench: dict[str, Any]) -> pd.DataFrame:
    rows = []
    for r in bench.get("overall", []):
        p = r.get("p_holm")
        rows.append(
            {
                "rank": r["rank"],
                "filter": r["label"],
                "gap to floor, geometric mean (×)": cell(r["score"], r["ci_lo"], r["ci_hi"]),
                "÷ lowest (paired)": cell(r["ratio"], r["ratio_lo"], r["ratio_hi"])
                if r.get("ratio") is not None
                else "",
                "p (Holm)": f"{r.get('p_holm_bound') or ''}{sig3(p)}" if p is not None else "",
                "verdict": r.get("verdict", ""),
                "unreliable on": f"{r['problems_unreliable']} of {r['problems']} problems",
            }
        )
    return pd.DataFrame(rows).set_index("rank") if rows else pd.DataFrame()


def problem_table(problem: dict[str, Any]) -> pd.DataFrame:
    rows = []
    for r in problem["rows"]:
        div, runs = r.get("diverged"), r.get("runs")
        rows.append(
            {
                "rank": "" if r.get("rank") is None else str(int(r["rank"])),
                "filter": r["label"],
                f"RMSE ({r['unit']})": cell(
                    r["value"], r.get("ci_lo") or math.nan, r.get("ci_hi") or math.nan
                ),
                "gap to floor (×)": cell(r["gap"], _num(r.get("gap_lo")), _num(r.get("gap_hi")))
                if r.get("gap") is not None
                else "—",
                "diverged": "" if div is None else (f"{int(div)} of {int(runs)}" if div else "0"),
                "µs/run·step": "" if r.get("us_per_run_step") is None else sig3(r["us_per_run_step"]),
                "tuned": r.get("tuned") or "",
                "verdict": r.get("vs_text") or r.get("verdict") or "",
            }
        )
    return pd.DataFrame(rows).set_index("rank")


def show(folder: str | None = None) -> None:
    """The page body."""
    bench = BN.load(folder)
    if bench is None:
        st.info(NO_BENCH, icon=":material/info:")
        return
    st.caption(f"{bench['description']}; run {bench['created']}, {bench['wall_s']:.0f} s wall time.")
    st.subheader("Overall standing")
    st.table(overall_table(bench))
    st.subheader("Gap to the floor on every problem")
    st.caption(
        "Each cell: the tuned filter's RMSE / the posterior Cramér–Rao bound on that problem "
        "(1× = no estimator can do better; the oracle, a genie told the outliers, can go below). "
        "Click a cell to open its problem's experiment on Compare (every filter, tuned, on the test "
        "seed: the same numbers); hover for the RMSE and the verdict; "
        "⚠: diverged in more than 5 % of the runs."
    )
    st.markdown(heat_map_html(bench), unsafe_allow_html=True)
    names = [p["name"] for p in bench["problems"]]
    pick = st.selectbox("Ranked table of a problem", names, key="lb_problem")
    prob = bench["problems"][names.index(pick)]
    if prob.get("floor"):
        v, lo, hi = prob["floor"]
        unit = prob["rows"][0]["unit"] if prob["rows"] else ""
        st.caption(
            f"Floor (posterior Cramér–Rao bound of the {prob['group']} RMSE): {sig3(v)} {unit}"
            + (f" [{sig3(lo)}, {sig3(hi)}]" if hi > lo else " (exact)")
        )
    st.table(problem_table(prob))
    st.caption("  \n".join(bench.get("notes", [])))
