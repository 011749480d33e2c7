"""Tables a paper can take: ``--format markdown|latex`` (navlab.tables.render), booktabs, value with
interval, bold only where the paired test backs it, units, a caption naming runs, seeds and interval
method. The LaTeX is compiled in a minimal document where a TeX engine is installed (pdflatex);
without one the text is checked.
"""

from __future__ import annotations

import re
import shutil
import subprocess

import pandas as pd
import pytest

from navlab import tables
from navlab.cli import main
from navlab.experiment import ExperimentSpec, run_experiment

SPEC = ExperimentSpec(scenario="cv2d", filters=("kf", "huber-kf", "oracle-kf"), runs=12, epochs=40, seed=3)


@pytest.fixture(scope="module")
def res():
    return run_experiment(SPEC)


def _body(tex: str) -> list[str]:
    """The rows between \\midrule and \\bottomrule."""
    return tex.split("\\midrule\n", 1)[1].split("\\bottomrule", 1)[0].strip().splitlines()


def test_latex_is_a_booktabs_table_with_caption_runs_seeds_interval(res):
    tex = tables.run_table(res, "latex")
    assert tex.isascii()  # pdflatex with no inputenc / unicode-math
    for part in ("\\begin{table}", "\\toprule", "\\midrule", "\\bottomrule", "\\end{table}", "\\label{"):
        assert part in tex, part
    cap = re.search(r"\\caption\{(.*)\}\n", tex).group(1)
    assert "12 Monte Carlo runs" in cap and "seed 3" in cap and "95 \\% interval" in cap
    assert "BCa bootstrap over runs" in cap  # 12 runs: the bootstrap (docs/STATISTICS.md)
    head = tex.split("\\toprule\n", 1)[1].split("\\midrule", 1)[0]
    assert "RMSE position (m)" in head and "$\\mu$s per run$\\cdot$step" in head  # units
    rows = _body(tex)
    assert [r.split(" & ")[0] for r in rows] == ["KF", "HKF (Huber)", "Oracle KF"]
    n = head.count(" & ")
    assert all(r.count(" & ") == n and r.endswith("\\\\") for r in rows)  # a rectangular table
    assert re.search(r"\d\.\d+ \[\d\.\d+, \d\.\d+\]", rows[0])  # value [lo, hi]
    assert tex.count("{") == tex.count("}")


def test_bold_exactly_where_the_paired_test_backs_it(res):
    t = tables.headline(res, best=True)
    tex = tables.latex_table(t, "c")
    bold = re.findall(r"\\textbf\{([^}]*)\}", tex)
    assert len(bold) == len(t.best)
    if t.best:  # each bold cell is the backed filter's cell of that column
        for col, label in t.best.items():
            assert tables.latex_escape(t.cells.loc[label, col]) in bold
    # the same cells without a backed winner: no bold at all (a point-estimate winner is not bold)
    assert "\\textbf" not in tables.latex_table(tables.Table(t.cells, t.notes), "c")


def test_bold_follows_table_best_only():
    cells = pd.DataFrame({"filter": ["A", "B"], "RMSE (m)": ["1.00 [0.9, 1.1]", "2.00 [1.9, 2.1]"]})
    t = tables.Table(cells.set_index("filter"), best={"RMSE (m)": "A"})
    assert "\\textbf{1.00 [0.9, 1.1]} \\\\" in tables.latex_table(t, "c")
    assert "| A | **1.00 [0.9, 1.1]** |" in tables.markdown_table(t, "c")
    assert "**" not in tables.markdown_table(tables.Table(cells.set_index("filter")), "c")


def test_markdown_is_a_pipe_table_with_caption(res):
    md = tables.run_table(res, "markdown", compare_to="kf")
    assert md.startswith("Table: ") and "12 Monte Carlo runs" in md.splitlines()[0]
    pipe = [line for line in md.splitlines() if line.startswith("|")]
    assert len(pipe) == 2 + 3 and len({line.count(" | ") for line in pipe[2:]}) == 1
    assert "vs KF" in pipe[0] and "reference" in pipe[2]


def test_latex_escape_is_ascii_and_safe():
    s = tables.latex_escape("R̂ error 5 % a_b & c {x} µs σ² Δ −1 … 的")
    assert s.isascii()
    assert "$\\hat{R}$" in s and "5 \\%" in s and "a\\_b" in s and "\\&" in s and "\\{x\\}" in s
    assert "$\\mu$" in s and "$\\sigma^2$" in s and "$\\Delta$" in s and "$-$1" in s and "?" in s


def test_cli_run_format_latex(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("NAVLAB_STORE", str(tmp_path))
    rc = main(
        [
            "run",
            "--scenario",
            "cv2d",
            "--filters",
            "kf,chi2-kf",
            "--runs",
            "10",
            "--epochs",
            "20",
            "--format",
            "latex",
            "-q",
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0 and out.startswith("% navlab table") and "\\toprule" in out


def test_a_minimal_document_compiles_where_pdflatex_exists(res, tmp_path):
    doc = (
        "\\documentclass{article}\n\\usepackage{booktabs}\n\\usepackage[margin=1cm,landscape]{geometry}\n"
        "\\begin{document}\n" + tables.run_table(res, "latex", compare_to="kf") + "\\end{document}\n"
    )
    assert doc.isascii()
    if shutil.which("pdflatex") is None:
        pytest.skip("no pdflatex on this machine: the LaTeX text is checked by the tests above")
    (tmp_path / "t.tex").write_text(doc)
    done = subprocess.run(
        ["pdflatex", "-interaction=nonstopmode", "-halt-on-error", "t.tex"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stdout[-3000:]
    assert (tmp_path / "t.pdf").stat().st_size > 0
