"""Text of a reproduction's verdicts: the CLI table, Markdown for the README, the rules.

Pure (no streamlit); the Reproduce page shows the same rows.
"""

from __future__ import annotations

import textwrap

import numpy as np
import pandas as pd

from navlab import stats as S
from navlab.reproduce.engine import TOLERANCE, Outcome, Reproduction

WIDTH = 100  # prose (notes, rules) wrapped to a terminal; the verdict table keeps its columns
RULES = (
    f"Verdicts (docs/STATISTICS.md §4): a number is reproduced when the mean over the seeds lies within "
    f"±{TOLERANCE:.0%} of the paper's value, contradicted when the whole 95 % interval of that mean lies "
    "outside the band, inconclusive otherwise; a bound likewise against the stated bound; a ranking is "
    "reproduced when the paired test over all runs pooled (Holm over the competitors) says better than "
    "each, contradicted when it says worse than at least one; a margin is judged as a number on the "
    "paired interval of the relative difference; 'close' reads every filter within ±10 % of the best. "
    "A seed is one Monte Carlo set of the paper's run count; 'holds' counts the seeds on which the "
    "claim holds by its point estimate. In a paired test a run lost (diverged) by one filter counts as a "
    "loss for it, scored as the worst run of the pair (docs/STATISTICS.md §5); p < …: a bound, below the "
    "bootstrap's resolution."
)


def _num(v: float, unit: str = "") -> str:
    s = S.sig3(v)
    return f"{s} {unit}".strip() if s and unit and unit not in ("relative", "ratio") else s


def navlab_cell(r: pd.Series) -> str:
    """What navlab found for one claim row, in words."""
    unit = r["unit"] if r["unit"] not in ("ratio", "relative", "relative spread") else ""
    if r["kind"] in ("number", "bound", "margin"):
        if not np.isfinite(r["mean"]):
            return "no value"
        if r["kind"] == "margin" and r["unit"] == "relative":
            if not np.isfinite(r["ci_lo"]):
                return f"{100 * r['mean']:+.1f} %"
            return f"{100 * r['mean']:+.1f} % [{100 * r['ci_lo']:+.1f}, {100 * r['ci_hi']:+.1f}]"
        if np.isfinite(r["ci_lo"]):
            return f"{_num(r['mean'])} [{_num(r['ci_lo'])}, {_num(r['ci_hi'])}] {unit}".strip()
        return _num(r["mean"], unit)
    if r["kind"] == "close":
        return f"spread {100 * r['mean']:.1f} %" if np.isfinite(r["mean"]) else "no value"
    if np.isfinite(r["mean"]):  # a ranking against one competitor: the pooled Δ
        if not np.isfinite(r["ci_lo"]):
            return f"Δ {_num(r['mean'], unit)}"
        return f"Δ {_num(r['mean'])} [{_num(r['ci_lo'])}, {_num(r['ci_hi'])}] {unit}".strip()
    return "see note"


def paper_cell(r: pd.Series) -> str:
    if r["kind"] == "number":
        return _num(r["paper"], r["unit"])
    if r["kind"] == "bound":
        return f"> {_num(r['paper'], r['unit'])}"
    if r["kind"] == "margin":
        return f"{100 * r['paper']:+.2f} %" if r["unit"] == "relative" else f"{_num(r['paper'])}"
    if r["kind"] == "close":
        return "close"
    return "holds"


def range_cell(r: pd.Series) -> str:
    if not np.isfinite(r["range_lo"]):
        return ""
    if r["kind"] == "margin" and r["unit"] == "relative":
        return f"{100 * r['range_lo']:+.1f}…{100 * r['range_hi']:+.1f} %"
    if r["kind"] == "close":
        return f"{100 * r['range_lo']:.1f}…{100 * r['range_hi']:.1f} %"
    return f"{_num(r['range_lo'])}…{_num(r['range_hi'])}"


def holds_cell(r: pd.Series) -> str:
    share, n = r["share_of_seeds_holding"], r["seeds"]
    if not (np.isfinite(share) and np.isfinite(n)):
        return ""
    return f"{round(share * n):d}/{int(n)}"


def verdict_table(o: Outcome) -> pd.DataFrame:
    """One display row per claim (text cells)."""
    rows = []
    for i, r in enumerate(o.verdicts.to_dict("records"), 1):
        r = pd.Series(r)
        rows.append(
            {
                "#": i,
                "claim": r["text"],
                "paper": paper_cell(r),
                "navlab (mean over seeds [95 %])": navlab_cell(r),
                "per-seed range": range_cell(r),
                "holds": holds_cell(r),
                "verdict": r["verdict"],
            }
        )
    return pd.DataFrame(rows)


def claims_table(rep: Reproduction, verdict: str = "not judged yet") -> pd.DataFrame:
    """The paper's claims before any seed is judged: the verdict table's first columns."""
    from navlab.reproduce.engine import Bound, Close, Margin, Number

    units = {q.name: q.unit for q in rep.quantities}
    rows = []
    for i, c in enumerate(rep.claims, 1):
        if isinstance(c, Number | Bound):
            r = {"kind": "number" if isinstance(c, Number) else "bound", "unit": units[c.quantity]}
            r["paper"] = c.paper if isinstance(c, Number) else c.bound
        elif isinstance(c, Margin):
            r = {"kind": "margin", "paper": c.paper, "unit": "ratio" if c.as_ratio else "relative"}
        else:
            r = {"kind": "close" if isinstance(c, Close) else "ranking", "paper": np.nan, "unit": ""}
        rows.append({"#": i, "claim": c.text, "paper": paper_cell(pd.Series(r)), "verdict": verdict})
    return pd.DataFrame(rows)


def header(o: Outcome) -> str:
    rep = o.reproduction
    return (
        f"{rep.title}\n{rep.paper}\n"
        f"{o.seeds} seeds × {o.runs} runs per seed (base seed {o.seed}; seed s = runs s·{o.runs} … "
        f"s·{o.runs} + {o.runs - 1})"
    )


def text(o: Outcome) -> str:
    """The CLI report: header, the verdict table, numbered notes, the rules."""
    from navlab.tables import text_table

    body = text_table(verdict_table(o), index=False)
    notes = [
        textwrap.fill(n, WIDTH, initial_indent=f"  {i}. ", subsequent_indent=" " * (4 + len(str(i))))
        for i, n in enumerate(o.verdicts["note"], 1)
        if n
    ]
    counts = o.verdicts["verdict"].value_counts()
    summary = ", ".join(f"{counts.get(v, 0)} {v}" for v in ("reproduced", "contradicted", "inconclusive"))
    return (
        f"{header(o)}\n\n{body}\n\n{len(o.verdicts)} claims: {summary}.\n\nNotes:\n"
        + "\n".join(notes)
        + f"\n\n{textwrap.fill(RULES, WIDTH)}\n"
    )


def markdown(o: Outcome) -> str:
    """The verdict table and its notes as Markdown (the README's reproduction summary is made
    from this: ``tools/readme_reproductions.py``).
    """
    t = verdict_table(o)
    cols = list(t.columns)
    rep = o.reproduction
    lines = [
        f"**{rep.key}** — {rep.title}; {o.seeds} seeds × {o.runs} runs, base seed "
        f"{o.seed}: `python -m navlab reproduce {rep.key} --seeds {o.seeds}`",
        "",
    ]
    lines.append("| " + " | ".join(cols) + " |")
    lines.append("|" + "---|" * len(cols))
    for row in t.itertuples(index=False):
        lines.append("| " + " | ".join(str(v).replace("|", "/") for v in row) + " |")
    notes = [f"{i}. {n}" for i, n in enumerate(o.verdicts["note"], 1) if n]
    if notes:
        lines += ["", "Notes (by claim number): " + " ".join(n.rstrip(".") + "." for n in notes)]
    return "\n".join(lines) + "\n"
