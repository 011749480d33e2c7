"""A run as a Jupyter notebook or a Python script that re-runs it with the library and redraws
its figures (the Compare page's "Notebook" and "Script" downloads).

Pure (no streamlit). Both carry the experiment's configuration JSON (the same the CLI reads with
``--config``) and run it with :func:`navlab.experiment.run_experiment`: run r always draws from
its own seed, so the re-run gives the numbers the page showed. They print the headline table,
write the tidy metrics to ``navlab-metrics.csv``, and redraw the chosen figures with the app's
own builders (:mod:`navlab.ui.figures`), saved as publication SVG and PNG
(:mod:`navlab.ui.export`). The notebook's last cell prints the headline RMSE as JSON (what the
browser test compares with the page's metrics).
"""

from __future__ import annotations

from collections.abc import Sequence

import nbformat

from navlab import __version__
from navlab.experiment import ExperimentSpec

# (file stem, Python expression of navlab.ui.figures on `res`)
Figure = tuple[str, str]


def default_figures(group: str = "pos", channel: int = 0) -> list[Figure]:
    """Compare's three charts: error over time, true R(t) vs R̂, NIS vs its χ² band."""
    return [
        ("error", f"F.error_vs_time(res, {group!r})"),
        ("rhat", f"F.r_vs_rhat(res, {int(channel)})"),
        ("nis", "F.nis_vs_chi2(res)"),
    ]


def _spec_literal(spec: ExperimentSpec) -> str:
    return 'ExperimentSpec.from_json(r"""\n' + spec.to_json(indent=2) + '\n""")'


HEADLINE_JSON = (
    "import json\n"
    "m = res.metrics()\n"
    "head = m[m.metric.str.startswith('rmse_')]\n"
    "print(json.dumps({f'{r.filter}|{r.metric}': r.value for r in head.itertuples()}))"
)


def script(spec: ExperimentSpec, figures: Sequence[Figure] | None = None) -> str:
    """A Python script that re-runs ``spec`` and redraws ``figures`` (default: Compare's)."""
    figures = list(figures or default_figures())
    figs = "\n".join(f"    {name!r}: {expr}," for name, expr in figures)
    return f'''"""Re-run a navlab experiment and redraw its figures (written by navlab {__version__}).

Run it where navlab is installed: python {{this file}}. It prints the headline table, writes
navlab-metrics.csv and each figure as SVG and PNG (navlab-<name>.svg / .png) next to it.
The same experiment on the command line: python -m navlab run --config navlab-config.json
"""

from navlab import tables
from navlab.experiment import ExperimentSpec, run_experiment
from navlab.ui import figures as F
from navlab.ui.export import save

SPEC = {_spec_literal(spec)}

res = run_experiment(SPEC)
print(tables.headline(res).text())
res.metrics().to_csv("navlab-metrics.csv", index=False)

figures = {{
{figs}
}}
for name, fig in figures.items():
    save(fig, f"navlab-{{name}}.svg")
    save(fig, f"navlab-{{name}}.png")
    print(f"wrote navlab-{{name}}.svg and .png")
'''


def notebook(spec: ExperimentSpec, figures: Sequence[Figure] | None = None) -> str:
    """A Jupyter notebook (nbformat 4, JSON text) that re-runs ``spec`` and redraws ``figures``."""
    figures = list(figures or default_figures())
    nb = nbformat.v4.new_notebook()
    md = nbformat.v4.new_markdown_cell
    code = nbformat.v4.new_code_cell
    cells = [
        md(
            f"# navlab experiment: {spec.scenario}, {len(spec.filters)} filters × {spec.runs} runs\n\n"
            f"Written by navlab {__version__}. Running it re-runs the experiment with the library "
            "(the same seed: the same numbers as the page) and redraws the figures: interactive "
            "with `fig.show()`, and as publication SVG/PNG files."
        ),
        code(
            "from IPython.display import SVG, display\n\n"
            "from navlab import tables\n"
            "from navlab.experiment import ExperimentSpec, run_experiment\n"
            "from navlab.ui import figures as F\n"
            "from navlab.ui.export import save, to_svg\n\n"
            f"SPEC = {_spec_literal(spec)}"
        ),
        code("res = run_experiment(SPEC)\nprint(tables.headline(res).text())"),
        code('metrics = res.metrics()\nmetrics.to_csv("navlab-metrics.csv", index=False)\nmetrics.head(20)'),
    ]
    for name, expr in figures:
        cells.append(md(f"## {name}"))
        cells.append(
            code(
                f"fig = {expr}\n"
                f'save(fig, "navlab-{name}.svg")\n'
                f'save(fig, "navlab-{name}.png")\n'
                "display(SVG(to_svg(fig)))  # fig.show() draws it interactively"
            )
        )
    cells.append(md("The headline RMSEs (filter|metric → value), as JSON:"))
    cells.append(code(HEADLINE_JSON))
    nb.cells = cells
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nbformat.validate(nb)
    return nbformat.writes(nb)
