"""MkDocs hooks: the pages generated from the code at build time.

- ``cli-reference.md``: every subcommand's ``--help`` from navlab's own argparse parser;
- ``filters.md``: every registered filter's summary, teaching text, equations and Params.

A page holds a marker (``<!-- generated: cli -->``, ``<!-- generated: filters -->``) that the
generated text replaces, so the reference cannot drift from the code.
"""

from __future__ import annotations

import os
from typing import Any


def cli_reference() -> str:
    """Every command's help text, as the parser prints it."""
    os.environ["COLUMNS"] = "100"  # argparse wraps to the terminal: a fixed width for the page
    from navlab.cli import build_parser

    p = build_parser()
    out = ["## navlab", "", "```text", p.format_help().rstrip(), "```", ""]
    sub = next(a for a in p._actions if a.__class__.__name__ == "_SubParsersAction")
    helps = {c.dest: c.help for c in sub._choices_actions}
    for name, sp in sub.choices.items():
        out += [f"## navlab {name}", "", helps.get(name) or "", ""]
        if name == "app":
            out += ["Starts the Streamlit app; every argument after `app` is Streamlit's.", ""]
            continue
        out += ["```text", sp.format_help().rstrip(), "```", ""]
    return "\n".join(out)


def _md(v: Any) -> str:
    return str(v).replace("|", "\\|").replace("\n", " ")


def filters_page() -> str:
    """Each filter: what it is, its teaching text and equations, its parameters."""
    from navlab.filters import registry
    from navlab.filters.base import FILTERS
    from navlab.params import describe

    out = []
    for key, cls in registry().items():
        out += [f"## {cls.label} (`{key}`)", ""]
        facts = [f"family: {cls.family}"]
        if cls.paper:
            facts.append(f"paper: {cls.paper}")
        if cls.spec_section:
            facts.append(f"specification: ALGORITHMS.md {cls.spec_section}")
        if cls.reconstruction:
            facts.append("reconstructed from a citation")
        if key in FILTERS.plugin_sources:
            facts.append(f"plugin: {FILTERS.plugin_sources[key]}")
        out += ["; ".join(facts) + ".", ""]
        if cls.summary:
            out += [cls.summary, ""]
        t = cls.teaching
        if t.idea:
            out += [t.idea, ""]
        for eq in t.equations:
            out += ["$$", eq, "$$", ""]
        if t.caveat:
            out += [f"*Caveat:* {t.caveat}", ""]
        if cls.kf_limit is not None:
            why = f": {cls.kf_limit.why}" if cls.kf_limit.why else ""
            out += [f"*The KF when* `{cls.kf_limit.params}`{why}", ""]
        params = describe(cls.Params)
        if params:
            out += ["| parameter | default | range | meaning |", "|---|---|---|---|"]
            for d in params:
                rng = "" if d["lo"] is None and d["hi"] is None else f"{d['lo']} … {d['hi']}"
                if d.get("choices"):
                    rng = ", ".join(map(str, d["choices"]))
                out.append(f"| `{d['name']}` | `{_md(d['default'])}` | {_md(rng)} | {_md(d['help'] or '')} |")
            out.append("")
    return "\n".join(out)


GENERATED = {"<!-- generated: cli -->": cli_reference, "<!-- generated: filters -->": filters_page}


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    for marker, make in GENERATED.items():
        if marker in markdown:
            markdown = markdown.replace(marker, make())
    return markdown
