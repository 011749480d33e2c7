"""Text of a reproduction's verdicts: the CLI table, Markdown for the docs, LaTeX for a paper, the rules.

Pure (no streamlit); the Reproduce page shows the same rows.
"""

from __future__ import annotations

import textwrap

import numpy as np
import pandas as pd

from navlab import stats as S
from navlab.reproduce.engine import TOLERANCE, VERDICTS, Outcome, Reproduction

WIDTH = 100  # prose (notes, rules) wrapped to a terminal; the verdict table keeps its columns
#: the rule of every verdict kind (docs/STATISTICS.md §4), printed with every table
VERDICT_RULES = {
    "reproduced": (
        f"a number within ±{TOLERANCE:.0%} of the paper's value (mean over the seeds); a bound with the "
        "95 % interval of the mean on the paper's side; a ranking when the paired test over all runs "
        "pooled (Holm over the competitors) says better than each; a margin as a number on the paired "
        "interval of the relative difference; 'close' when every filter's paired interval lies within "
        "±10 % of the best"
    ),
    "contradicted": (
        f"the whole 95 % interval of the mean outside the ±{TOLERANCE:.0%} band (a number, a margin) or on "
        "the other side of the bound; the paired test says worse than at least one (a ranking); an "
        "interval entirely outside ±10 % of the best ('close')"
    ),
    "inconclusive": "neither: the interval straddles the band, the bound or 0 at this seed count",
    "setup-dependent": (
        "reproduced under navlab's setting and contradicted under a documented alternative setting or "
        "reading (or the reverse): both verdicts are in the note; the alternatives are listed with the "
        "claim in docs/CLAIMS.md"
    ),
    "not testable": (
        "what the claim needs is a reconstruction of equations the paper's text lost that fails "
        "(diverges in more than 5 % of the runs), or the paper gives too little to test (no number, no "
        "measure, a property of its real data): the note says which"
    ),
}
RULES_FOOT = (
    "‡: a setting navlab chose where the paper is silent or with the judged scenario in view (the note "
    "names it). A seed is one Monte Carlo set of the paper's run count; 'holds' counts the seeds on which "
    "the claim holds by its point estimate. In a paired test a run lost (diverged) by one filter counts "
    "as a loss for it, scored as the worst run of the pair (docs/STATISTICS.md §5); p < …: a bound, below "
    "the bootstrap's resolution."
)
RULES = (
    "Verdicts (docs/STATISTICS.md §4): "
    + " ".join(f"{k.upper()}: {v}." for k, v in VERDICT_RULES.items())
    + " "
    + RULES_FOOT
)


def _num(v: float, unit: str = "") -> str:
    s = S.sig3(v)
    return f"{s} {unit}".strip() if s and unit and unit not in ("relative", "ratio") else s


def navlab_cell(r: pd.Series) -> str:
    """What navlab found for one claim row, in words."""
    unit = r["unit"] if r["unit"] not in ("ratio", "relative", "relative spread") else ""
    if r["kind"] == "untested":
        return "—"
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
    if r["kind"] == "untested":
        return "see source"
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
                "claim": claim_cell(r["text"], r["chosen"]),
                "source": r["where"],
                "paper": paper_cell(r),
                "navlab (mean over seeds [95 %])": navlab_cell(r),
                "per-seed range": range_cell(r),
                "holds": holds_cell(r),
                "verdict": r["verdict"],
            }
        )
    return pd.DataFrame(rows)


def claim_cell(text: str, chosen: str) -> str:
    """A claim's text, marked ‡ where a setting navlab chose touches it."""
    return f"{text} ‡" if chosen else text


def counts(o: Outcome) -> dict[str, int]:
    """The number of claims of every verdict kind (every kind, zeros included)."""
    got = o.verdicts["verdict"].value_counts()
    return {v: int(got.get(v, 0)) for v in VERDICTS}


def rules_text() -> str:
    """The rule of every verdict kind, one per line."""
    return "\n".join(f"- {k}: {v}." for k, v in VERDICT_RULES.items())


def claims_table(rep: Reproduction, verdict: str = "not judged yet") -> pd.DataFrame:
    """The paper's claims before any seed is judged: the verdict table's first columns."""
    from navlab.reproduce.engine import Bound, Close, Margin, Number, Untested

    units = {q.name: q.unit for q in rep.quantities}
    rows = []
    for i, c in enumerate(rep.claims, 1):
        if isinstance(c, Number | Bound):
            r = {"kind": "number" if isinstance(c, Number) else "bound", "unit": units[c.quantity]}
            r["paper"] = c.paper if isinstance(c, Number) else c.bound
        elif isinstance(c, Untested):
            r = {"kind": "untested", "paper": np.nan, "unit": ""}
        elif isinstance(c, Margin):
            r = {"kind": "margin", "paper": c.paper, "unit": "ratio" if c.as_ratio else "relative"}
        else:
            r = {"kind": "close" if isinstance(c, Close) else "ranking", "paper": np.nan, "unit": ""}
        v = "not testable" if isinstance(c, Untested) else verdict
        rows.append(
            {
                "#": i,
                "claim": claim_cell(c.text, c.chosen),
                "source": c.where,
                "paper": paper_cell(pd.Series(r)),
                "verdict": v,
            }
        )
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
    summary = ", ".join(f"{n} {v}" for v, n in counts(o).items())
    rules = "\n".join(
        textwrap.fill(line, WIDTH, subsequent_indent="    ") for line in rules_text().splitlines()
    )
    return (
        f"{header(o)}\n\n{body}\n\n{len(o.verdicts)} claims: {summary}.\n\nNotes:\n"
        + "\n".join(notes)
        + f"\n\nVerdicts (docs/STATISTICS.md §4):\n{rules}\n{textwrap.fill(RULES_FOOT, WIDTH)}\n"
    )


def markdown(o: Outcome) -> str:
    """The verdict table and its notes as Markdown (docs/reproductions.md's summary is made from
    this: ``tools/readme_reproductions.py``).
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
    summary = ", ".join(f"{n} {v}" for v, n in counts(o).items())
    lines += ["", f"{len(o.verdicts)} claims: {summary}."]
    if notes:
        lines += ["", "Notes (by claim number): " + " ".join(n.rstrip(".") + "." for n in notes)]
    return "\n".join(lines) + "\n"


def latex(o: Outcome) -> str:
    """The verdict table as a booktabs LaTeX table (navlab.tables.latex_table): the caption names
    the reproduction, seeds and runs and the interval method; the claims' notes under it.
    """
    from navlab.tables import Table, latex_table

    rep = o.reproduction
    cells = verdict_table(o).set_index("#")
    notes = [f"{i}. {n}" for i, n in enumerate(o.verdicts["note"], 1) if n]
    summary = ", ".join(f"{n} {v}" for v, n in counts(o).items())
    caption = (
        f"{rep.title} ({rep.paper}): navlab's reproduction {rep.key}, {o.seeds} seeds x {o.runs} Monte "
        f"Carlo runs per seed (base seed {o.seed}; seed s = runs s*{o.runs} to s*{o.runs} + {o.runs - 1}). "
        "navlab: mean over the seeds with its 95 % t interval over seeds; verdicts as in navlab's "
        f"docs/STATISTICS.md section 4. {len(o.verdicts)} claims: {summary}."
    )
    return latex_table(Table(cells, notes), caption, label=f"tab:navlab-{rep.key}")


# --------------------------------------------------------------------------- the claims register

REGISTER_HEAD = """# Claims register

Every claim of the four papers' text and figures that navlab's reproductions judge, one entry per
claim, each with the sentence or figure it comes from. Generated from the claims declared in
`navlab/reproduce/*.py` by `python tools/claims_register.py` (a test checks this file against them):
the reproduction table (`python -m navlab reproduce NAME`) has one row per entry, in this order. The
verdict kinds and their rules are in docs/STATISTICS.md §4; ‡ marks an entry a setting navlab chose
touches (where the paper is silent or with the judged scenario in view); "alternatives" are the
documented other settings or readings the entry is also judged under (a flip between them makes it
*setup-dependent*); "needs" names a reconstruction of equations the paper's text lost (if it fails,
the entry is *not testable*). An out-of-scope entry says why.
"""


def _form(c) -> str:
    from navlab.reproduce.engine import Bound, Close, Margin, Number, Ranking, Untested

    if isinstance(c, Untested):
        return "not testable"
    if isinstance(c, Ranking):
        return "ranking (worst)" if c.worst else "ranking"
    return {Number: "number", Bound: "bound", Margin: "margin", Close: "close"}[type(c)]


def _md(v: str) -> str:
    return str(v).replace("|", "/").replace("\n", " ")


def register_markdown() -> str:
    """docs/CLAIMS.md: every registered reproduction's claims, in table order."""
    from navlab.reproduce.engine import REPRODUCTIONS, Untested

    out = [REGISTER_HEAD]
    for key in sorted(REPRODUCTIONS):
        rep = REPRODUCTIONS[key]
        forms = pd.Series([_form(c) for c in rep.claims]).value_counts()
        out += [
            f"## {key} — {rep.paper}",
            "",
            f"{len(rep.claims)} entries ({', '.join(f'{n} {f}' for f, n in forms.items())}); "
            f"`python -m navlab reproduce {key}`.",
            "",
            "| # | id | claim | form | source | quote | scope |",
            "|---|---|---|---|---|---|---|",
        ]
        for i, c in enumerate(rep.claims, 1):
            scope = []
            if isinstance(c, Untested):
                scope.append(f"out of scope: {c.reason}")
            if c.chosen:
                scope.append(f"‡ {c.chosen}")
            if c.needs:
                scope.append(f"needs navlab's reconstruction of {', '.join(c.needs)}")
            for a in c.alternatives:
                scope.append(f"alternative{'' if a.decides else ' (shown only)'}: {a.label}")
            cells = (
                i,
                f"`{c.id}`",
                claim_cell(c.text, c.chosen),
                _form(c),
                c.where,
                c.quote,
                "; ".join(scope),
            )
            out.append("| " + " | ".join(_md(v) for v in cells) + " |")
        out.append("")
    return "\n".join(out)
