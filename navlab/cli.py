"""Command-line interface: ``python -m navlab list|run|reproduce|sweep|tune|check-filter|app``.

Exit codes: 0 success; 2 a problem with the arguments, the configuration or an input file (one
line on stderr saying what to change); 1 an unexpected internal error, or (check-filter) a
contract the filter breaks.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
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
    from navlab.filters.base import FILTERS, registry
    from navlab.noise import OUTLIERS, SCHEDULES
    from navlab.scenarios.base import scenario_registry

    if what == "filters":
        rows = [
            (
                k,
                c.label,
                c.family,
                ("reconstruction" if c.reconstruction else ""),
                FILTERS.plugin_sources.get(k, "navlab"),
                c.summary,
            )
            for k, c in registry().items()
        ]
        return pd.DataFrame(rows, columns=["key", "label", "family", "note", "from", "summary"])
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


def _check_outputs(a: argparse.Namespace) -> None:
    """Refuse an output path that cannot be written before the computation, not after it."""
    seen: dict[Path, str] = {}
    for flag in ("out", "save_spec", "save_results"):
        if getattr(a, flag, None):
            what = f"--{flag.replace('_', '-')} {getattr(a, flag)}"
            p = Path(getattr(a, flag)).expanduser().resolve()
            if p in seen and (p.is_file() or not p.exists()):  # the second would overwrite the first
                raise NavlabError(f"{seen[p]} and {what} name the same file; give each its own")
            seen[p] = what
            _writable(Path(getattr(a, flag)), what, folder=False)
    if getattr(a, "outdir", None):
        _writable(Path(a.outdir), f"--outdir {a.outdir}", folder=True)


def _writable(p: Path, what: str, folder: bool) -> None:
    """NavlabError unless file ``p`` can be written (or folder ``p`` made and written into)."""
    if p.exists() and p.is_dir() != folder:
        got, want = ("file", "folder") if folder else ("folder", "file name")
        raise NavlabError(f"{what}: that is a {got}; give a {want}")
    parent = p if folder else p.parent
    while folder and not parent.exists() and parent != parent.parent:  # the run makes the missing folders
        parent = parent.parent
    if not parent.is_dir():
        why = "is a file, not a folder; give" if parent.exists() else "does not exist; create it or give"
        raise NavlabError(f"{what}: {parent} {why} another path")
    if not os.access(parent, os.W_OK | os.X_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise NavlabError(f"{what}: no permission to write there; give a path you can write to")


def _spec_from_args(a: argparse.Namespace):
    from navlab.experiment import ExperimentSpec

    base: dict[str, Any] = {}
    if a.config:
        from navlab.io import MAX_JSON_BYTES, read_text

        text = read_text(a.config, f"--config {a.config}", max_bytes=MAX_JSON_BYTES)
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
    # the flags that are shortcuts for a parameter override the configuration's value of it
    shortcut = {
        "contamination": "outliers.contamination",
        "outlier_scale": "outliers.scale",
        "epochs": "scenario.epochs",
    }
    given = {shortcut[k]: k for k in shortcut if overrides[k] is not None}
    for dotted in given:
        group, name = dotted.split(".")
        base.get({"outliers": "outlier_params", "scenario": "scenario_params"}[group], {}).pop(name, None)
    for item in a.set or []:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise NavlabError(
                f"--set takes GROUP.NAME=VALUE (e.g. chi2-kf.alpha=0.05 or outliers.contamination=0.2), "
                f"got {item!r}"
            )
        lhs, rhs = item.split("=", 1)
        group, name = lhs.split(".", 1)
        if not group or not name:
            raise NavlabError(f"--set {item}: name the group and the parameter, e.g. chi2-kf.alpha=0.05")
        if lhs in given:
            flag = "--" + given[lhs].replace("_", "-")
            raise NavlabError(f"--set {item} and {flag} both set {lhs}; give it once")
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
    if "runs" not in base:  # the scenario's own default (1 on a recording whose runs are all alike)
        from navlab.scenarios import scenario_registry

        scls = scenario_registry().get(base.get("scenario", "cv2d"))
        if scls is not None:
            base["runs"] = scls.default_runs
    return ExperimentSpec.from_dict(base)


def _run(a: argparse.Namespace) -> int:
    from navlab.experiment import run_experiment

    spec = _spec_from_args(a)
    if a.compare_to is not None and a.compare_to not in spec.filters:
        raise NavlabError(
            f"--compare-to {a.compare_to}: not one of the filters run ({', '.join(spec.filters)})"
        )
    if a.save_results and a.summary:
        raise NavlabError(
            "--save-results needs the per-epoch arrays, which --summary drops: run without --summary"
        )
    progress = _progress(a.quiet)
    if progress is not None:
        progress.total = spec.runs
    # on a terminal, chunks of a tenth (each chunk repeats the epoch loop); elsewhere one chunk,
    # with a line every few seconds from within it (a long run shows it is alive)
    chunk = max(1, spec.runs // 10) if progress is not None and progress.tty else None
    if a.summary:
        from navlab.experiment import run_summary

        res = run_summary(spec, on_progress=progress, budget=a.memory_budget)
    else:
        within = None if progress is None else progress.within
        res = run_experiment(
            spec, on_progress=progress, chunk_runs=chunk, budget=a.memory_budget, on_epoch=within
        )
    if a.format == "table":
        from navlab.tables import headline

        _write(headline(res, compare_to=a.compare_to).text(), a.out)
    elif a.format in ("markdown", "latex"):
        from navlab.tables import run_table

        _write(run_table(res, a.format, compare_to=a.compare_to), a.out)
    else:
        from navlab.tables import summary_rows

        _emit(summary_rows(res, compare_to=a.compare_to), a.format, a.out)
    if a.save_results:
        from navlab.experiment import save_results

        save_results(res, a.save_results)
        print(f"wrote {a.save_results} (navlab.load_results reads it)", file=sys.stderr)
    if a.save_spec:
        try:
            Path(a.save_spec).write_text(spec.to_json(indent=1), encoding="utf-8")
        except OSError as exc:
            raise NavlabError(f"cannot write --save-spec {a.save_spec}: {exc.strerror}") from None
    from navlab.data.checks import run_messages  # real data: what was fed, checks, can it be trusted

    for finding in run_messages(res):
        print(f"navlab: {finding}", file=sys.stderr)
    return 0


class _Progress:
    """Progress on stderr: a counter rewritten in place on a terminal; elsewhere (a log file, a
    pipe) a line every :attr:`EVERY_S` seconds, also while nothing finishes (``tick``), so a
    stalled job shows. ``where()`` says where the work runs (an executor's ``now``).
    """

    EVERY_S = 5.0

    def __init__(self, what: str, where: Any = None) -> None:
        self.what, self.where = what, where
        self.tty = sys.stderr.isatty()
        self.t0 = self.last = time.monotonic()
        self.done = self.total = 0

    def __call__(self, done: int, total: int) -> None:
        self.done, self.total = done, total
        if self.tty:
            print(
                f"\r{done}/{total} {self.what}", end="" if done < total else "\n", file=sys.stderr, flush=True
            )
        else:
            self.tick()

    def within(self, done: float) -> None:
        """Runs done within a chunk (fractional): a line off a terminal every ``EVERY_S``."""
        if not self.tty:
            self.done = round(done, 1)
            self.tick()

    def tick(self) -> None:
        now = time.monotonic()
        if self.tty or now - self.last < self.EVERY_S:
            return
        self.last = now
        where = f" · {self.where()}" if self.where is not None else ""
        done, total = self.done, self.total  # within a chunk a fraction of the runs: said as a share
        count = f"{done}/{total}" if done == int(done) else f"{100 * done / total:.0f} % of {total}"
        print(
            f"navlab: {count} {self.what} after {now - self.t0:.0f} s{where}",
            file=sys.stderr,
            flush=True,
        )


def _progress(quiet: bool, what: str = "runs", where: Any = None) -> _Progress | None:
    """Progress on stderr (:class:`_Progress`), or None with ``--quiet``."""
    return None if quiet else _Progress(what, where)


def _reproduce(a: argparse.Namespace) -> int:
    from navlab.reproduce import REPRODUCTIONS
    from navlab.reproduce import report as R

    if a.name not in REPRODUCTIONS:
        raise NavlabError(
            f"unknown reproduction '{a.name}'; known: {', '.join(REPRODUCTIONS) or '(none yet)'}"
        )
    rep = REPRODUCTIONS[a.name]
    o = rep.evaluate(runs=a.runs, seeds=a.seeds, seed=a.seed, on_progress=_progress(a.quiet), jobs=a.jobs)
    table = o.readings if a.details else o.verdicts
    if a.format == "table":
        _write(table.to_string(index=False) + "\n" if a.details else R.text(o), a.out)
    elif a.format == "markdown":
        _write(R.markdown(o), a.out)
    elif a.format == "latex":
        _write(R.latex(o), a.out)
    else:
        _emit(table, a.format, a.out)
    if a.outdir:
        out = Path(a.outdir)
        try:
            out.mkdir(parents=True, exist_ok=True)
            o.verdicts.to_csv(out / f"{rep.key}_verdicts.csv", index=False)
            (out / f"{rep.key}_verdicts.md").write_text(R.markdown(o), encoding="utf-8")
            o.readings.to_csv(out / f"{rep.key}_readings.csv", index=False)
            for name, df in o.curves.items():
                df.to_csv(out / name, index=False)
        except OSError as exc:
            raise NavlabError(f"cannot write --outdir {a.outdir}: {exc.strerror}") from None
        print(f"wrote {len(o.curves) + 2} CSV files and the verdicts as Markdown to {out}", file=sys.stderr)
    return 0


def app_command(args: Sequence[str]) -> list[str]:
    """The ``streamlit run app.py`` command line for ``navlab app ARGS`` (Streamlit's own flags,
    e.g. ``--server.port 8611``, passed through; a leading ``--`` is dropped).
    """
    app = Path(__file__).resolve().parent.parent / "app.py"
    if not app.exists():
        raise NavlabError(f"app.py not found next to the navlab package ({app})")
    args = list(args)
    if args[:1] == ["--"]:
        args = args[1:]
    return [sys.executable, "-m", "streamlit", "run", str(app), *args]


def _app(args: Sequence[str]) -> int:
    """Become the Streamlit server (exec): stopping ``navlab app`` stops the server.

    It runs in app.py's folder, whatever the caller's: Streamlit reads navlab's
    ``.streamlit/config.toml`` from the working directory (a relative NAVLAB_DATA is made absolute
    first, so it still names the same folder).
    """
    cmd = app_command(args)
    if os.environ.get("NAVLAB_DATA"):
        os.environ["NAVLAB_DATA"] = os.path.abspath(os.environ["NAVLAB_DATA"])
    os.chdir(Path(cmd[4]).parent)
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(cmd[0], cmd)
    return 0  # not reached


def _floats(text: str, what: str) -> list[float]:
    """'0,0.1,0.2' or 'LO:HI:N' (linear) or 'LO:HI:N:log' → values."""
    from navlab import sweep as SW

    try:
        if ":" in text:
            parts = text.split(":")
            lo, hi, n = float(parts[0]), float(parts[1]), int(parts[2])
            log = len(parts) > 3 and parts[3] == "log"
            if len(parts) > 4 or (len(parts) == 4 and not log) or n < 1:
                raise ValueError
            if log and lo <= 0:
                raise NavlabError(f"{what} {text}: a log-spaced range needs a positive lower end")
            if n > SW.MAX_POINTS:  # refused before numpy allocates them
                most = SW.MAX_POINTS
                raise NavlabError(f"{what} {text}: {n} values; a sweep takes at most {most} per axis")
            return list(SW.spaced(lo, hi, n, log))
        return [float(v) for v in text.split(",") if v.strip()]
    except NavlabError:  # a ValueError too, but already in words
        raise
    except ValueError:
        raise NavlabError(
            f"{what} takes comma-separated numbers (0,0.1,0.2) or LO:HI:N[:log], got {text!r}"
        ) from None


def _seeds(text: str | None, what: str) -> list[int] | None:
    if text is None:
        return None
    try:
        out = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise NavlabError(f"{what} takes comma-separated whole numbers (e.g. 11,12), got {text!r}") from None
    from navlab.params import SEED_MAX

    if not out or any(not 0 <= v <= SEED_MAX for v in out):
        raise NavlabError(f"{what} takes comma-separated whole numbers in [0, {SEED_MAX}], got {text!r}")
    return out


def _engine(a: argparse.Namespace):
    """(store, executor) of the sweep/tune options."""
    from navlab.cluster import executor
    from navlab.store import Store

    return Store.open(a.store), executor(a.scheduler)


def _ran(ex: Any, quiet: bool) -> None:
    """Where the tasks ran, and why (stderr)."""
    if not quiet:
        print(f"navlab: ran {ex.report}", file=sys.stderr)


def _sweep(a: argparse.Namespace) -> int:
    from navlab import sweep as SW

    spec = _spec_from_args(a)
    axes = []
    for name, values, flag in ((a.param, a.values, "--values"), (a.param2, a.values2, "--values2")):
        if name is None:
            if values is not None:
                raise NavlabError(f"{flag} needs its parameter ({flag.replace('values', 'param')})")
            continue
        if values is None:
            raise NavlabError(f"{name}: give its values with {flag} (e.g. 0,0.1,0.2 or 0:0.3:7)")
        p = SW.resolve(spec, name)
        axes.append(SW.Axis(p, tuple(SW.check_values(p, _floats(values, flag)))))
    if a.param is None:
        raise NavlabError("--param GROUP.NAME is required (e.g. outliers.contamination)")
    store, ex = _engine(a)
    sw = SW.make_sweep(spec, axes)
    prog = _progress(a.quiet, "tasks", lambda: ex.now)
    out = SW.run_sweep(sw, store=store, executor=ex, on_progress=prog, tick=prog and prog.tick)
    _ran(ex, a.quiet)
    df = out.rows
    if a.metric and a.metric not in set(df.metric):  # the sweep is in the store: a re-run is quick
        raise NavlabError(
            f"--metric {a.metric}: not a metric of this sweep; e.g. {', '.join(dict.fromkeys(df.metric))}"
        )
    if a.format not in ("table", "markdown", "latex"):
        if a.metric:
            df = df[df.metric == a.metric]
        _emit(df, a.format, a.out)
        return 0
    metric = a.metric or _headline_metric(spec)
    if a.format in ("markdown", "latex"):
        _write(SW.paper_tables(out, sw, metric, a.format), a.out)
    else:
        _write(SW.text(out, sw, metric), a.out)
    return 0


def _headline_metric(spec) -> str:
    from navlab.scenarios.base import get_scenario_class

    head = get_scenario_class(spec.scenario).headline
    return f"rmse_{head[0] if head else 'pos'}"


def _tune(a: argparse.Namespace) -> int:
    from navlab import tune as TU

    spec = _spec_from_args(a)
    st = TU.setup(
        spec,
        budget=a.budget,
        objective=a.objective,
        train_seeds=_seeds(a.train_seeds, "--train-seeds"),
        test_seeds=_seeds(a.test_seeds, "--test-seeds"),
        train_runs=a.train_runs,
        ranges=a.range or (),
    )
    store, ex = _engine(a)
    prog = _progress(a.quiet, "tasks", lambda: ex.now)
    r = TU.tune(st, store=store, executor=ex, on_progress=prog, tick=prog and prog.tick)
    _ran(ex, a.quiet)
    if a.format == "table":
        _write(TU.report(r).text(), a.out)
    elif a.format in ("markdown", "latex"):
        _write(TU.paper_table(r, a.format), a.out)
    else:
        _emit(r.rows, a.format, a.out)
    if a.outdir:
        out = Path(a.outdir)
        try:
            out.mkdir(parents=True, exist_ok=True)
            for k in spec.filters:
                (out / f"tuned-{k}.json").write_text(r.tuned_spec(k).to_json(indent=1), encoding="utf-8")
            (out / "tuned.json").write_text(r.tuned_spec().to_json(indent=1), encoding="utf-8")
            r.rows.to_csv(out / "tune.csv", index=False)
            TU.trials_frame(r).to_csv(out / "trials.csv", index=False)
        except OSError as exc:
            raise NavlabError(f"cannot write --outdir {a.outdir}: {exc.strerror}") from None
        print(
            f"wrote {len(spec.filters) + 1} configurations (tuned-FILTER.json, tuned.json: navlab run "
            f"--config), tune.csv and trials.csv to {out}",
            file=sys.stderr,
        )
    return 0


def _bench(a: argparse.Namespace) -> int:
    from navlab import bench as BN

    suite = BN.get_suite(a.suite)
    filters = [f.strip() for f in a.filters.split(",") if f.strip()] if a.filters else None
    if a.estimate:
        say = None if a.quiet else (lambda sc: print(f"navlab: timing the filters on {sc}", file=sys.stderr))
        df, tot = BN.estimate(suite, filters, on_scenario=say)
        if a.format != "table":
            _emit(df, a.format, a.out)
            return 0
        dur = lambda s: f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min" if s < 7200 else f"{s / 3600:.1f} h"  # noqa: E731
        walls = ", ".join(f"{w} worker{'s' * (w > 1)} ≈ {dur(v)}" for w, v in tot["wall_s"].items())
        _write(
            f"{suite.describe()}.\n{tot['tasks']} tasks, {tot['cpu_hours']:.3g} CPU-hours on this machine "
            f"(per-task times from timed tasks of every filter); wall time {walls} (the bench's "
            "batches one after the other, each max(CPU / workers, its longest task); dispatch left out)\n",
            a.out,
        )
        return 0
    if not a.outdir:  # the default folder (--outdir is checked with the other outputs)
        _writable(BN.default_dir(), f"the bench folder {BN.default_dir()} (NAVLAB_BENCH_DIR)", folder=True)
    store, ex = _engine(a)
    prog = _progress(a.quiet, "tasks", lambda: ex.now)
    b = BN.run(suite, filters=filters, store=store, executor=ex, on_progress=prog, tick=prog and prog.tick)
    _ran(ex, a.quiet)
    if a.format == "table":
        _write(BN.text(b), a.out)
    elif a.format in ("markdown", "latex"):
        _write(BN.paper(b, a.format), a.out)
    else:
        _emit(BN.rows(b), a.format, a.out)
    where = BN.save(b, a.outdir)
    if not a.quiet:
        print(f"navlab: wrote {where} (the Leaderboard page shows it)", file=sys.stderr)
    return 0


def _engine_options(p: argparse.ArgumentParser) -> None:
    """Where sweep/tune tasks run and are kept."""
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="Dask scheduler (tcp://HOST:8786) to send the tasks to; 'local' (default, or "
        "NAVLAB_DASK_SCHEDULER): an embedded cluster on this machine; 'serial': this process",
    )
    p.add_argument(
        "--store",
        metavar="DIR",
        help="results store folder (default NAVLAB_STORE or ~/.cache/navlab/store; 'off': none)",
    )
    p.add_argument("--format", choices=["table", "json", "csv", "markdown", "latex"], default="table")
    p.add_argument("--out", help="write the output to this file instead of stdout")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")


def _experiment_options(p: argparse.ArgumentParser) -> None:
    """The options that define an experiment (run, sweep, tune)."""
    p.add_argument("--config", help="experiment spec JSON (flags given here override it)")
    p.add_argument("--scenario", help="scenario key (default cv2d)")
    p.add_argument(
        "--filters",
        type=lambda s: [x.strip() for x in s.split(",") if x.strip()],
        help="comma-separated filter keys",
    )
    p.add_argument("--runs", type=int, help="Monte Carlo runs")
    p.add_argument("--seed", type=int, help="base seed")
    p.add_argument("--epochs", type=int, help="number of epochs (default: the scenario's)")
    p.add_argument("--noise-schedule", help="true R(t) schedule key")
    p.add_argument("--outliers", help="outlier model key")
    p.add_argument("--contamination", type=float, help="outlier ratio α (mixture)")
    p.add_argument("--outlier-scale", type=float, help="outlier scale κ (in σ)")
    p.add_argument(
        "--set",
        action="append",
        metavar="GROUP.NAME=VALUE",
        help="a parameter: FILTER.NAME=V, noise.NAME=V, outliers.NAME=V, scenario.NAME=V",
    )


def _add_list_command(sub: Any) -> None:
    """The ``list`` subcommand."""
    pl = sub.add_parser("list", help="list filters, scenarios, schedules, outliers, reproductions")
    pl.add_argument("what", choices=["filters", "scenarios", "schedules", "outliers", "reproductions"])
    pl.add_argument("--format", choices=["table", "json", "csv"], default="table")


def _add_check_filter_command(sub: Any) -> None:
    """The ``check-filter`` subcommand: the contract suite on one filter."""
    pc = sub.add_parser(
        "check-filter",
        help="check a filter against the contracts (batched = run by run, PSD, NaN channel, reference, …)",
    )
    pc.add_argument("name", help="the filter's key (navlab list filters), e.g. one of your plugin's")
    pc.add_argument(
        "--scenario",
        action="append",
        help="check on this scenario only (repeatable; default: every compatible scenario)",
    )
    pc.add_argument("--verbose", "-v", action="store_true", help="also list the checks that pass")


def _check_filter(a: argparse.Namespace) -> int:
    from navlab.contracts import check_filter

    counts = {"pass": 0, "fail": 0, "skip": 0}
    skipped: dict[str, list[Any]] = {}

    def show(o) -> None:
        counts[o.status] += 1
        if o.status == "fail":
            print(f"FAIL  {o.contract} [{o.scenario}]: {o.message}", flush=True)
        elif o.status == "skip":
            skipped.setdefault(o.message, []).append(o)
        elif a.verbose:
            print(f"pass  {o.contract} [{o.scenario}]", flush=True)

    check_filter(a.name, a.scenario, on_outcome=show)
    for why, outs in skipped.items():
        where = sorted({o.scenario for o in outs})
        what = outs[0].contract if len(outs) == 1 else f"{len(outs)} checks"
        print(f"skip  {what} [{', '.join(where)}]: {why}")
    if not counts["pass"] and not counts["fail"]:  # not "passed": nothing was checked
        raise NavlabError(f"{a.name}: nothing checked — all {counts['skip']} checks skipped (why: above)")
    verdict = "FAILED" if counts["fail"] else "passed"
    print(f"{a.name}: {verdict} — {counts['pass']} passed, {counts['fail']} failed, {counts['skip']} skipped")
    return 1 if counts["fail"] else 0


def _add_run_command(sub: Any) -> None:
    """The ``run`` subcommand: a Monte Carlo experiment and its metrics."""
    pr = sub.add_parser("run", help="run a Monte Carlo experiment and print its metrics")
    _experiment_options(pr)
    pr.add_argument(
        "--compare-to",
        metavar="FILTER",
        help="reference filter: add each other filter's paired difference (95 %% interval, "
        "p-value, verdict) per headline metric",
    )
    pr.add_argument(
        "--format",
        choices=["table", "json", "csv", "markdown", "latex"],
        default="table",
        help="markdown, latex: the headline table for a paper (booktabs; value [95 %% interval]; bold "
        "only where the paired test backs it; caption with runs, seeds and interval method)",
    )
    pr.add_argument("--out", help="write the output to this file instead of stdout")
    pr.add_argument("--save-spec", help="also write the resolved spec JSON here")
    pr.add_argument(
        "--save-results",
        metavar="FILE.nc",
        help="also write the result cube (filter × run × epoch × channel: truth, estimates, R̂, flags; "
        "the spec and navlab's version as attributes) as netCDF; navlab.load_results reads it",
    )
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


def _add_reproduce_command(sub: Any) -> None:
    """The ``reproduce`` subcommand: a paper's claims over many seeds."""
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
    pp.add_argument("--format", choices=["table", "json", "csv", "markdown", "latex"], default="table")
    pp.add_argument(
        "--details",
        action="store_true",
        help="print the detailed readings (every quantity of every filter) instead of the verdicts",
    )
    pp.add_argument("--out", help="write the output to this file")
    pp.add_argument("--outdir", help="directory for the verdicts, readings and RMSE curves (CSV)")
    pp.add_argument(
        "--jobs",
        default=None,
        help="worker processes (default: NAVLAB_JOBS or the cores available; the numbers are the "
        "same for any value)",
    )
    pp.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")


def _add_sweep_command(sub: Any) -> None:
    """The ``sweep`` subcommand: one or two parameters swept."""
    ps = sub.add_parser("sweep", help="sweep one or two parameters: every point's metrics with intervals")
    _experiment_options(ps)
    ps.add_argument("--param", metavar="GROUP.NAME", help="parameter to sweep, as in --set")
    ps.add_argument("--values", help="its values: V1,V2,… or LO:HI:N[:log]")
    ps.add_argument("--param2", metavar="GROUP.NAME", help="a second parameter (2-D sweep)")
    ps.add_argument("--values2", help="the second parameter's values")
    ps.add_argument(
        "--metric",
        help="the metric to report: the table's (default: the headline RMSE); json/csv keep its rows only",
    )
    _engine_options(ps)


def _add_tune_command(sub: Any) -> None:
    """The ``tune`` subcommand: every filter tuned on the same budget."""
    pt = sub.add_parser("tune", help="tune every filter on the same budget; default vs tuned on test seeds")
    _experiment_options(pt)
    pt.add_argument(
        "--budget",
        type=int,
        default=16,
        help="candidates per filter (the default + BUDGET−1 Sobol points), successive halving (default 16)",
    )
    pt.add_argument(
        "--objective",
        help="metric to minimise on the training seeds (default rmse_pos: the headline RMSE); "
        "consistent_<metric>: × a penalty when the ANEES leaves its χ² band",
    )
    pt.add_argument("--train-seeds", metavar="S,…", help="training seeds (default: --seed + 1)")
    pt.add_argument("--test-seeds", metavar="S,…", help="test seeds, --runs runs each (default: --seed)")
    pt.add_argument(
        "--train-runs",
        type=int,
        default=None,
        help="runs per training seed on the last successive-halving rung (default 32, or the "
        "scenario's default runs when fewer: 1 on smartloc-berlin, whose runs are all alike)",
    )
    pt.add_argument(
        "--range",
        action="append",
        metavar="FILTER.NAME=LO:HI",
        help="search range of a parameter (overrides its declared one, or adds one)",
    )
    pt.add_argument("--outdir", help="write tuned-FILTER.json configurations, tune.csv and trials.csv here")
    _engine_options(pt)


def _add_bench_command(sub: Any) -> None:
    """The ``bench`` subcommand: every registered filter, tuned, on a fixed suite."""
    pb = sub.add_parser(
        "bench", help="every filter tuned on the same budget over a fixed suite: ranked tables, floor, cost"
    )
    pb.add_argument(
        "--suite",
        choices=["tiny", "small", "full"],
        default="small",
        help="the suite (default small; tiny: a first look)",
    )
    pb.add_argument("--filters", help="comma-separated filter keys (default: every registered filter)")
    pb.add_argument(
        "--outdir",
        help="folder of last-bench.json, which the Leaderboard page shows (default NAVLAB_BENCH_DIR "
        "or ~/.cache/navlab/bench)",
    )
    pb.add_argument(
        "--estimate",
        action="store_true",
        help="print the suite's cost (tasks, CPU-hours, wall time on 1/2/8/64 workers) from timed "
        "tasks of every filter, without running it",
    )
    _engine_options(pb)


def build_parser() -> argparse.ArgumentParser:
    from navlab import __version__

    p = _Parser(prog="navlab", description="navlab: robust and adaptive Kalman filters lab")
    p.add_argument("--version", action="version", version=f"navlab {__version__}")
    p.add_argument(
        "--debug", action="store_true", help="show tracebacks of internal errors (also after the subcommand)"
    )
    sub = p.add_subparsers(dest="cmd", required=True, parser_class=_Parser)
    for add in (
        _add_list_command,
        _add_run_command,
        _add_reproduce_command,
        _add_sweep_command,
        _add_tune_command,
        _add_bench_command,
        _add_check_filter_command,
    ):
        add(sub)
    sub.add_parser(
        "app",
        help="start the Streamlit app (Streamlit's flags pass through, e.g. --server.port 8611)",
        add_help=False,
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        rest = [x for x in argv if x != "--debug"]
        if rest[:1] == ["app"]:  # everything after "app" is Streamlit's
            return _app(rest[1:])
        a = build_parser().parse_args(rest)  # --debug is taken before or after the subcommand
        _check_outputs(a)
        if a.cmd == "list":
            _emit(_list(a.what), a.format, None)
            return 0
        if a.cmd == "run":
            return _run(a)
        if a.cmd == "reproduce":
            return _reproduce(a)
        if a.cmd == "sweep":
            return _sweep(a)
        if a.cmd == "tune":
            return _tune(a)
        if a.cmd == "bench":
            return _bench(a)
        if a.cmd == "check-filter":
            return _check_filter(a)
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
