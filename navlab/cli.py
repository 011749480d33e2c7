"""Command-line interface: ``python -m navlab list|run|reproduce|app``.

Exit codes: 0 success; 2 a problem with the arguments, the configuration or an input file (one
line on stderr saying what to change); 1 an unexpected internal error.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from navlab.errors import NavlabError

log = logging.getLogger(__name__)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2, no usage dump
        sub = " ".join(self.prog.split()[1:])
        raise NavlabError(f"{message} (see 'python -m navlab {sub + ' ' if sub else ''}--help')")


def _list(what: str) -> pd.DataFrame:
    from navlab.filters.base import registry
    from navlab.noise import OUTLIERS, SCHEDULES
    from navlab.scenarios.base import scenario_registry

    if what == "filters":
        rows = [
            (k, c.label, c.family, ("reconstruction" if c.reconstruction else ""), c.summary)
            for k, c in registry().items()
        ]
        return pd.DataFrame(rows, columns=["key", "label", "family", "note", "summary"])
    if what == "scenarios":
        rows = [(k, c.label, c.paper, c.summary) for k, c in scenario_registry().items()]
        return pd.DataFrame(rows, columns=["key", "label", "paper", "summary"])
    if what == "schedules":
        return pd.DataFrame([(k, c.summary) for k, c in SCHEDULES.items()], columns=["key", "summary"])
    if what == "outliers":
        return pd.DataFrame([(k, c.summary) for k, c in OUTLIERS.items()], columns=["key", "summary"])
    if what == "reproductions":
        from navlab.reproduce import REPRODUCTIONS

        return pd.DataFrame([(k, r.title) for k, r in REPRODUCTIONS.items()], columns=["key", "title"])
    raise NavlabError(f"nothing called '{what}' to list")


def _emit(df: pd.DataFrame, fmt: str, out: str | None) -> None:
    """A tidy table as JSON records (NaN → null), CSV (NaN → empty) or text (NaN → empty)."""
    if fmt == "json":
        records = json.loads(df.to_json(orient="records", double_precision=15))
        text = json.dumps(records, indent=1, ensure_ascii=False) + "\n"
    elif fmt == "csv":
        text = df.to_csv(index=False)
    else:
        with pd.option_context(
            "display.width",
            200,
            "display.max_columns",
            50,
            "display.max_colwidth",
            80,
            "display.max_rows",
            10000,
        ):
            text = df.astype(object).where(df.notna(), "").to_string(index=False) + "\n"
    _write(text, out)


def _write(text: str, out: str | None) -> None:
    if out:
        try:
            Path(out).write_text(text, encoding="utf-8")
        except OSError as exc:
            raise NavlabError(f"cannot write --out {out}: {exc.strerror}") from None
        print(f"wrote {out}", file=sys.stderr)
    else:
        sys.stdout.write(text)


def _spec_from_args(a: argparse.Namespace):
    from navlab.experiment import ExperimentSpec

    base: dict[str, Any] = {}
    if a.config:
        try:
            text = Path(a.config).read_text(encoding="utf-8")
        except OSError as exc:
            raise NavlabError(f"cannot read --config {a.config}: {exc.strerror}") from None
        base = ExperimentSpec.from_json(text).to_dict()
    overrides = {
        "scenario": a.scenario,
        "filters": a.filters,
        "runs": a.runs,
        "seed": a.seed,
        "epochs": a.epochs,
        "noise_schedule": a.noise_schedule,
        "outliers": a.outliers,
        "contamination": a.contamination,
        "outlier_scale": a.outlier_scale,
    }
    base.update({k: v for k, v in overrides.items() if v is not None})
    for item in a.set or []:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise NavlabError(f"--set takes GROUP.NAME=VALUE (e.g. kf.alpha=0.05), got {item!r}")
        lhs, rhs = item.split("=", 1)
        group, name = lhs.split(".", 1)
        try:
            value = json.loads(rhs)
        except json.JSONDecodeError:
            value = rhs
        target = {"noise": "noise_params", "outliers": "outlier_params", "scenario": "scenario_params"}
        if group in target:
            base.setdefault(target[group], {})[name] = value
        else:
            base.setdefault("filter_params", {}).setdefault(group, {})[name] = value
    if "scenario" in base and a.scenario and not a.filters and not a.config:
        from navlab.scenarios.base import get_scenario_class

        base["filters"] = list(get_scenario_class(base["scenario"]).default_filters)
    return ExperimentSpec.from_dict(base)


def _run(a: argparse.Namespace) -> int:
    from navlab.experiment import run_experiment

    spec = _spec_from_args(a)
    progress = None
    if sys.stderr.isatty() and not a.quiet:

        def progress(done: int, total: int) -> None:
            print(f"\r{done}/{total} runs", end="" if done < total else "\n", file=sys.stderr)

    # chunks only pay off when someone watches the progress (each chunk repeats the epoch loop)
    chunk = max(1, spec.runs // 10) if progress is not None else None
    if a.summary:
        from navlab.experiment import run_summary

        res = run_summary(spec, on_progress=progress, budget=a.memory_budget)
    else:
        res = run_experiment(spec, on_progress=progress, chunk_runs=chunk, budget=a.memory_budget)
    if a.compare_to is not None and a.compare_to not in spec.filters:
        raise NavlabError(
            f"--compare-to {a.compare_to}: not one of the filters run ({', '.join(spec.filters)})"
        )
    if a.format == "table":
        from navlab.tables import headline

        _write(headline(res, compare_to=a.compare_to).text(), a.out)
    else:
        from navlab.metrics import summarize

        _emit(summarize(res, compare_to=a.compare_to), a.format, a.out)
    if a.save_spec:
        try:
            Path(a.save_spec).write_text(spec.to_json(indent=1), encoding="utf-8")
        except OSError as exc:
            raise NavlabError(f"cannot write --save-spec {a.save_spec}: {exc.strerror}") from None
    return 0


def _progress(quiet: bool, what: str = "runs"):
    """A one-line progress counter on stderr (a terminal only), or None."""
    if quiet or not sys.stderr.isatty():
        return None

    def show(done: int, total: int) -> None:
        print(f"\r{done}/{total} {what}", end="" if done < total else "\n", file=sys.stderr, flush=True)

    return show


def _reproduce(a: argparse.Namespace) -> int:
    from navlab.reproduce import REPRODUCTIONS
    from navlab.reproduce import report as R

    if a.name not in REPRODUCTIONS:
        raise NavlabError(
            f"unknown reproduction '{a.name}'; known: {', '.join(REPRODUCTIONS) or '(none yet)'}"
        )
    rep = REPRODUCTIONS[a.name]
    o = rep.evaluate(runs=a.runs, seeds=a.seeds, seed=a.seed, on_progress=_progress(a.quiet))
    table = o.readings if a.details else o.verdicts
    if a.format == "table":
        _write(table.to_string(index=False) + "\n" if a.details else R.text(o), a.out)
    elif a.format == "markdown":
        _write(R.markdown(o), a.out)
    else:
        _emit(table, a.format, a.out)
    if a.outdir:
        out = Path(a.outdir)
        try:
            out.mkdir(parents=True, exist_ok=True)
            o.verdicts.to_csv(out / f"{rep.key}_verdicts.csv", index=False)
            o.readings.to_csv(out / f"{rep.key}_readings.csv", index=False)
            for name, df in o.curves.items():
                df.to_csv(out / name, index=False)
        except OSError as exc:
            raise NavlabError(f"cannot write --outdir {a.outdir}: {exc.strerror}") from None
        print(f"wrote {len(o.curves) + 2} CSV files to {out}", file=sys.stderr)
    return 0


def _app(a: argparse.Namespace) -> int:
    app = Path(__file__).resolve().parent.parent / "app.py"
    if not app.exists():
        raise NavlabError(f"app.py not found next to the navlab package ({app})")
    cmd = [sys.executable, "-m", "streamlit", "run", str(app), *a.streamlit_args]
    return subprocess.call(cmd)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="navlab", description="navlab: robust and adaptive Kalman filters lab")
    p.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    sub = p.add_subparsers(dest="cmd", required=True, parser_class=_Parser)

    pl = sub.add_parser("list", help="list filters, scenarios, schedules, outliers, reproductions")
    pl.add_argument("what", choices=["filters", "scenarios", "schedules", "outliers", "reproductions"])
    pl.add_argument("--format", choices=["table", "json", "csv"], default="table")

    pr = sub.add_parser("run", help="run a Monte Carlo experiment and print its metrics")
    pr.add_argument("--config", help="experiment spec JSON (flags given here override it)")
    pr.add_argument("--scenario", help="scenario key (default cv2d)")
    pr.add_argument(
        "--filters",
        type=lambda s: [x.strip() for x in s.split(",") if x.strip()],
        help="comma-separated filter keys",
    )
    pr.add_argument("--runs", type=int, help="Monte Carlo runs")
    pr.add_argument("--seed", type=int, help="base seed")
    pr.add_argument("--epochs", type=int, help="number of epochs (default: the scenario's)")
    pr.add_argument("--noise-schedule", help="true R(t) schedule key")
    pr.add_argument("--outliers", help="outlier model key")
    pr.add_argument("--contamination", type=float, help="outlier ratio α (mixture)")
    pr.add_argument("--outlier-scale", type=float, help="outlier scale κ (in σ)")
    pr.add_argument(
        "--set",
        action="append",
        metavar="GROUP.NAME=VALUE",
        help="a parameter: FILTER.NAME=V, noise.NAME=V, outliers.NAME=V, scenario.NAME=V",
    )
    pr.add_argument(
        "--compare-to",
        metavar="FILTER",
        help="reference filter: add each other filter's paired difference (95 %% interval, "
        "p-value, verdict) per headline metric",
    )
    pr.add_argument("--format", choices=["table", "json", "csv"], default="table")
    pr.add_argument("--out", help="write the output to this file instead of stdout")
    pr.add_argument("--save-spec", help="also write the resolved spec JSON here")
    pr.add_argument(
        "--summary",
        action="store_true",
        help="keep only per-run statistics (metrics with intervals, no per-epoch arrays): for "
        "very large runs (up to 10 000 000 runs, computed in chunks that fit the memory budget)",
    )
    pr.add_argument(
        "--memory-budget",
        metavar="SIZE",
        help="refuse a run expected to hold more than this (e.g. 8GB; default: NAVLAB_MEMORY_BUDGET "
        "or half of the available memory)",
    )
    pr.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")

    pp = sub.add_parser("reproduce", help="judge a paper's claims over many Monte Carlo seeds")
    pp.add_argument("name", help="hakf, irakf, nnmfukf or vbekf")
    pp.add_argument(
        "--seeds",
        type=int,
        default=20,
        help="Monte Carlo sets ('seeds' in the papers' sense) of --runs runs each (default 20)",
    )
    pp.add_argument("--runs", type=int, default=None, help="runs per seed (default: the paper's)")
    pp.add_argument("--seed", type=int, default=1, help="base seed")
    pp.add_argument("--format", choices=["table", "json", "csv", "markdown"], default="table")
    pp.add_argument(
        "--details",
        action="store_true",
        help="print the detailed readings (every quantity of every filter) instead of the verdicts",
    )
    pp.add_argument("--out", help="write the output to this file")
    pp.add_argument("--outdir", help="directory for the verdicts, readings and RMSE curves (CSV)")
    pp.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")

    pa = sub.add_parser("app", help="start the Streamlit app")
    pa.add_argument("streamlit_args", nargs=argparse.REMAINDER)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        a = build_parser().parse_args(argv)
        if a.cmd == "list":
            _emit(_list(a.what), a.format, None)
            return 0
        if a.cmd == "run":
            return _run(a)
        if a.cmd == "reproduce":
            return _reproduce(a)
        if a.cmd == "app":
            return _app(a)
        return 2
    except NavlabError as exc:
        print(f"navlab: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("navlab: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # an internal error: one line unless --debug
        if debug or os.environ.get("NAVLAB_DEBUG"):
            raise
        print(f"navlab: internal error: {type(exc).__name__}: {exc} (rerun with --debug)", file=sys.stderr)
        return 1
