"""Seed-robust reproductions: a paper's claims judged over many Monte Carlo sets (docs/STATISTICS.md §4).

A "seed" in the papers' sense is one Monte Carlo set of the paper's run count N. A reproduction
runs S such sets as ONE batched experiment of S·N runs (set s is runs s·N … s·N + N − 1 of the
base seed, so set 0 is the old single-seed result), reduced chunk by chunk to per-run statistics
(:class:`Quantity`), and turns every claim of the paper into one row with a verdict:

* **a number** (:class:`Number`, "IRAKF x-position RMSE 1.5942 m"): the mean over the S sets, its
  95 % t interval, and the 2.5–97.5 % range of the per-set values (what another lab with another
  seed would plausibly see). *reproduced* if |mean − paper| ≤ 20 % of the paper's value;
  *contradicted* if the whole interval of the mean lies outside that band; *inconclusive*
  otherwise. The note says whether the paper's value is inside the per-set range (a lucky-seed
  match is not a reproduction) and whether it lies below the oracle filter's floor.
* **a bound** (:class:`Bound`, "SKF's peak error above 10 m"): *reproduced* if the interval of the
  mean lies on the paper's side of the bound, *contradicted* if it lies on the other side.
* **a ranking** (:class:`Ranking`, "A better than B", "A best"): the share of sets on which it
  holds, and the paired test of §3 on all S·N runs pooled (Holm over the competitors for "best").
  *reproduced* if the pooled test says A better than each; *contradicted* if it says A worse than
  at least one; *inconclusive* otherwise.
* **a margin** (:class:`Margin`, "A is 27 % better than B"): the paired interval of the relative
  difference (A − B)/B over all runs pooled; verdict as for a number (±20 % of the paper's margin).

Every filter is judged on the same runs (navlab.metrics' divergence rule, per experiment).

A claim may carry documented :class:`Alternative` settings or readings: judged under each too, it
is *setup-dependent* when the decisive verdict flips between them. A claim the paper gives too
little to test is an :class:`Untested` row, and a claim that ``needs`` a reconstruction of lost
equations which fails (diverges in more than 5 % of the runs) is *not testable* (:func:`combine`).

The runs of every experiment are computed in fixed blocks of whole seeds (seeds 0, 1, 2–3, 4–7,
…: :func:`seed_ranges`; a range larger than :data:`BLOCK_BYTES` of per-epoch arrays is split), in
``jobs`` worker processes (``--jobs``, ``NAVLAB_JOBS``; default the cores available; one BLAS
thread each) when there is enough work, and joined in run order, so the numbers are the same for
any ``jobs``. Each block is reduced to the per-run features in its worker; only those (and the
float32 curves) travel back. :func:`iter_evaluate` judges the claims each time the seeds counted
from 0 are all finished (the first verdicts after one seed: provisional, exactly those of a
reproduction with that many seeds) and keeps every finished block in a results store
(:mod:`navlab.store`) when given one, so a stopped or repeated reproduction resumes.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import itertools
import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from navlab import memory
from navlab import stats as S
from navlab.errors import NavlabError
from navlab.experiment import MAX_RUNS, ExperimentSpec, fixed_chunks, iter_chunks, plan, run_size
from navlab.metrics import judge, sq_error
from navlab.registry import Registry
from navlab.store import Store, key_of

Array = np.ndarray
TOLERANCE = 0.20  # a number is reproduced within ±20 % of the paper's value
DEFAULT_SEEDS = 20
JOBS_ENV = "NAVLAB_JOBS"  # worker processes of a reproduction (default: the cores available)
# the full arrays of one block of runs (each worker computes one at a time; a worker's peak RSS is
# about twice this: ≈ 0.7 GB for hakf's blocks of 200 runs)
BLOCK_BYTES = 512 * 2**20
POLL_S = 0.2  # while waiting on the worker processes, call tick() this often (the app's Stop)
POOL_MIN_STEPS = 1_000_000  # filter steps (runs × epochs × filters) below which one process is faster
_BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

ErrFn = Callable[[Any, Any], Array]  # (data, filter run) -> (B, K+1) squared error, display units²
WindowFn = Callable[[Any], Array]  # data -> (K+1,) bool


# --------------------------------------------------------------------------- quantities


def group_error(group: str) -> ErrFn:
    """Squared error norm of a metric group of the scenario (display units²)."""
    return lambda data, fr: sq_error(fr.x, data.x_true, data.groups[group])


def component_error(idx: Sequence[int], scale: float = 1.0) -> ErrFn:
    """Squared error norm of state components ``idx`` (times ``scale``)."""
    idx = list(idx)

    def err(data, fr):
        with np.errstate(over="ignore", invalid="ignore"):
            return (((fr.x[..., idx] - data.x_true[..., idx]) * scale) ** 2).sum(axis=-1)

    return err


def epochs(lo: int | None = None, hi: int | None = None) -> WindowFn:
    """Epochs lo … hi inclusive (None: the scenario's analysis window)."""

    def win(data):
        if lo is None and hi is None:
            return np.asarray(data.window, dtype=bool)
        k = np.arange(data.K + 1)
        return (k >= (lo if lo is not None else 1)) & (k <= (hi if hi is not None else data.K))

    return win


@dataclass(frozen=True)
class Quantity:
    """A statistic of one filter: per-run features (computed chunk by chunk) → an estimator.

    ``features(data, fr) -> {name: (B, …)}``; ``make(features of a set of runs) -> Estimator``.
    ``lower_is_better`` orders filters in rankings.
    """

    name: str
    unit: str
    features: Callable[[Any, Any], dict[str, Array]]
    make: Callable[[dict[str, Array]], S.Estimator]
    lower_is_better: bool = True
    help: str = ""


def pooled_rmse(name: str, unit: str, err: ErrFn, win: WindowFn | None = None, help: str = "") -> Quantity:
    """sqrt(mean over the window's epochs and the runs of the squared error)."""
    win = win or epochs()

    def feats(data, fr):
        sq = err(data, fr)[:, win(data)]
        return {"sse": sq.sum(axis=1), "n": np.full(sq.shape[0], float(sq.shape[1]))}

    return Quantity(name, unit, feats, lambda f: S.Ratio(f["sse"], f["n"], sqrt=True), help=help)


def mean_rmse(name: str, unit: str, err: ErrFn, win: WindowFn | None = None, help: str = "") -> Quantity:
    """Mean over the window's epochs of the per-epoch Monte Carlo RMSE."""
    win = win or epochs()

    def feats(data, fr):
        return {"sq": err(data, fr)[:, win(data)].astype(np.float32)}

    return Quantity(name, unit, feats, lambda f: S.MeanSqrtRatio(f["sq"]), help=help)


def peak_rmse(name: str, unit: str, err: ErrFn, win: WindowFn | None = None, help: str = "") -> Quantity:
    """The largest per-epoch Monte Carlo RMSE in the window."""
    win = win or epochs()

    def feats(data, fr):
        return {"sq": err(data, fr)[:, win(data)].astype(np.float32)}

    return Quantity(name, unit, feats, lambda f: S.MaxSqrtRatio(f["sq"]), help=help)


def mean_norm(name: str, unit: str, err: ErrFn, win: WindowFn | None = None, help: str = "") -> Quantity:
    """Mean over the window's epochs and the runs of the error norm (not squared)."""
    win = win or epochs()

    def feats(data, fr):
        with np.errstate(over="ignore", invalid="ignore"):
            e = np.sqrt(err(data, fr)[:, win(data)])
        return {"s": e.sum(axis=1), "n": np.full(e.shape[0], float(e.shape[1]))}

    return Quantity(name, unit, feats, lambda f: S.Ratio(f["s"], f["n"]), help=help)


def run_peak(name: str, unit: str, err: ErrFn, win: WindowFn | None = None, help: str = "") -> Quantity:
    """Mean over runs of each run's largest error norm in the window."""
    win = win or epochs()

    def feats(data, fr):
        with np.errstate(over="ignore", invalid="ignore"):
            e = np.sqrt(err(data, fr)[:, win(data)])
        return {"mx": e.max(axis=1), "one": np.ones(e.shape[0])}

    return Quantity(name, unit, feats, lambda f: S.Ratio(f["mx"], f["one"]), help=help)


def rate(
    name: str, hits: Callable[[Any, Any], tuple[Array, Array]], help: str = "", lower_is_better: bool = True
) -> Quantity:
    """A share in %: ``hits(data, fr) -> (hits (B,), opportunities (B,))``."""

    def feats(data, fr):
        h, o = hits(data, fr)
        return {"h": np.asarray(h, dtype=float), "o": np.asarray(o, dtype=float)}

    return Quantity(name, "%", feats, lambda f: S.Ratio(f["h"], f["o"], scale=100.0), lower_is_better, help)


# --------------------------------------------------------------------------- claims


@dataclass(frozen=True)
class Ref:
    """A (experiment, filter) pair a claim is about."""

    experiment: str
    filter: str


@dataclass(frozen=True, kw_only=True)
class Source:
    """Where a claim of the register comes from and what navlab chose for it (keywords only)."""

    where: str = ""  # where in the paper: section, figure, table
    quote: str = ""  # the sentence (or figure/table caption) the claim comes from
    chosen: str = ""  # a setting of navlab's chosen where the paper is silent / on this scenario
    alternatives: tuple[Alternative, ...] = ()  # documented alternative settings or readings
    needs: tuple[str, ...] = ()  # filters that are navlab's reconstruction of lost equations


@dataclass(frozen=True)
class Number(Source):
    """The paper gives a number for ``ref``'s ``quantity``."""

    id: str
    text: str
    ref: Ref
    quantity: str
    paper: float
    note: str = ""


@dataclass(frozen=True)
class Bound(Source):
    """The paper says ``ref``'s ``quantity`` is above (or below) ``bound``."""

    id: str
    text: str
    ref: Ref
    quantity: str
    bound: float
    above: bool = True
    note: str = ""


@dataclass(frozen=True)
class Ranking(Source):
    """The paper says ``better`` beats every one of ``than`` on ``quantity`` ("best" if several)."""

    id: str
    text: str
    better: Ref
    than: tuple[Ref, ...]
    quantity: str
    note: str = ""
    worst: bool = False  # the claim is the reverse: ``better`` is WORSE than every one of ``than``


@dataclass(frozen=True)
class Margin(Source):
    """The paper says (a − b)/b = ``paper`` on ``quantity`` (``as_ratio``: it states a/b)."""

    id: str
    text: str
    a: Ref
    b: Ref
    quantity: str
    paper: float  # the paper's relative difference (a − b)/b, or the ratio a/b if as_ratio
    as_ratio: bool = False
    note: str = ""


@dataclass(frozen=True)
class Close(Source):
    """The paper says the filters ``refs`` are close on ``quantity``; navlab reads "close" as
    every relative difference to the best within ±``within``.
    """

    id: str
    text: str
    refs: tuple[Ref, ...]
    quantity: str
    within: float = 0.10
    note: str = ""


@dataclass(frozen=True)
class Untested(Source):
    """A claim of the paper navlab cannot test: its row's verdict is "not testable", ``reason``
    says why (the paper gives too little, or what it needs is out of the reproduction's scope).
    """

    id: str
    text: str
    reason: str
    note: str = ""


@dataclass(frozen=True)
class Alternative:
    """A documented alternative setting or reading of a claim: ``claim`` is the same claim judged
    under it (other experiment, filter variant or quantity). ``decides``: a flip of the verdict
    under it makes the claim *setup-dependent*; False: shown beside the verdict only (e.g. navlab's
    own variant of a filter, which is not the paper's).
    """

    label: str
    claim: Claim
    decides: bool = True


Claim = Number | Bound | Ranking | Margin | Close | Untested

#: every verdict a row can carry (docs/STATISTICS.md §4; the rules: navlab.reproduce.report.RULES)
VERDICTS = ("reproduced", "contradicted", "inconclusive", "setup-dependent", "not testable")
DECISIVE = ("reproduced", "contradicted")


# --------------------------------------------------------------------------- the reproduction


@dataclass(frozen=True)
class Experiment:
    """One experiment of a paper: a spec (its ``runs`` = the paper's run count N per set)."""

    name: str
    spec: ExperimentSpec
    label: str = ""


@dataclass(frozen=True)
class Curve:
    """A per-epoch RMSE curve to show (e.g. the paper's figure)."""

    name: str
    unit: str
    err: ErrFn


@dataclass(frozen=True)
class Reproduction:
    """A paper's experiments, the quantities measured on every filter, and the paper's claims.

    :meth:`evaluate` runs ``seeds`` sets of ``runs`` runs (default: the paper's count) and
    returns an :class:`Outcome`.
    """

    key: str
    title: str
    paper: str
    experiments: tuple[Experiment, ...]
    quantities: tuple[Quantity, ...]
    claims: tuple[Claim, ...]
    curves: tuple[Curve, ...] = ()
    names: dict[str, str] = field(default_factory=dict)  # filter key -> the paper's name
    paper_runs: int | None = None
    notes: dict[str, str] = field(default_factory=dict)  # quantity or claim id -> why it may differ

    @property
    def default_runs(self) -> int:
        return int(self.paper_runs or self.experiments[0].spec.runs)

    def name(self, key: str) -> str:
        """The paper's name for a filter, else its registry label."""
        if key in self.names:
            return self.names[key]
        from navlab.filters.base import registry

        cls = registry().get(key)
        return cls.label if cls is not None else key

    def evaluate(
        self,
        runs: int | None = None,
        seeds: int = DEFAULT_SEEDS,
        seed: int = 1,
        on_progress: Callable[[int, int], None] | None = None,
        jobs: int | None = None,
        store: Store | None = None,
        stream: bool | None = None,
    ) -> Outcome:
        """:func:`evaluate` of this reproduction."""
        return evaluate(
            self, runs, seeds, seed, on_progress=on_progress, jobs=jobs, store=store, stream=stream
        )


#: Every registered reproduction, by key: each module of navlab.reproduce registers its own
#: (imported on first use, so the CLI and the app see a new one without touching a list).
REPRODUCTIONS: Registry[Reproduction] = Registry("reproduction", package="navlab.reproduce")
register = REPRODUCTIONS.register


@dataclass(eq=False)
class Measured:
    """Per-run features of every (filter, quantity) of one experiment over all S·N runs."""

    experiment: Experiment
    labels: dict[str, str]
    feats: dict[tuple[str, str], dict[str, Array]]  # (filter, quantity) -> features
    judged: dict[str, Array]  # filter -> (S·N,) bool
    reliable: dict[str, bool]
    lost: dict[str, int]
    curves: dict[tuple[str, str], tuple[Array, Array]]  # (filter, curve) -> Σ e², count per epoch
    t: Array
    valid: dict[str, Array] = field(default_factory=dict)  # filter -> (S·N,) bool: not diverged


@dataclass(eq=False)
class Outcome:
    """What a reproduction found on its first ``seeds`` seeds (of ``seeds_asked``): one verdict
    row per claim, the evidence of the qualitative claims (every paired relative difference a
    ranking or a "close" claim rests on, with its interval), the curves, and the detailed
    readings (computed on first use: a bootstrap per quantity and filter).
    """

    reproduction: Reproduction
    verdicts: pd.DataFrame
    evidence: pd.DataFrame
    curves: dict[str, pd.DataFrame]
    seeds: int
    runs: int
    seed: int
    seeds_asked: int
    evaluator: _Evaluator = field(repr=False)

    @property
    def complete(self) -> bool:
        """Whether every seed asked for is judged (else the verdicts are provisional)."""
        return self.seeds >= self.seeds_asked

    @functools.cached_property
    def readings(self) -> pd.DataFrame:
        return _readings(self.reproduction, self.evaluator)


@dataclass(eq=False)
class _Block:
    """What one block of runs of one experiment measured, before the judgement (picklable)."""

    start: int
    runs: int
    labels: dict[str, str]
    feats: dict[tuple[str, str], dict[str, Array]]
    curves: dict[tuple[str, str], Array]  # (filter, curve) -> (b, K+1) float32 squared errors
    diverged: dict[str, Array]
    t: Array


def _measure_block(rep: Reproduction, spec: ExperimentSpec, start: int, stop: int) -> _Block:
    """Runs start … stop − 1 of ``spec`` (one chunk): every quantity's features and curve."""
    p = plan(spec.replace(runs=stop))
    (ch,) = iter_chunks(p, fixed_chunks(stop - start), start)
    feats: dict[tuple[str, str], dict[str, Array]] = {}
    curves: dict[tuple[str, str], Array] = {}
    with np.errstate(over="ignore", invalid="ignore"):
        for key, fr in ch.runs.items():
            for q in rep.quantities:
                feats[(key, q.name)] = q.features(ch.data, fr)
            for c in rep.curves:
                curves[(key, c.name)] = c.err(ch.data, fr).astype(np.float32)
    return _Block(
        start,
        stop - start,
        {f.key: f.label for f in p.filters},
        feats,
        curves,
        {k: fr.diverged for k, fr in ch.runs.items()},
        np.asarray(ch.data.t),
    )


def _assemble(exp: Experiment, blocks: Sequence[_Block]) -> Measured:
    """The blocks of one experiment (in run order) joined and judged."""
    blocks = sorted(blocks, key=lambda b: b.start)
    first = blocks[0]
    jd = judge({k: np.concatenate([b.diverged[k] for b in blocks]) for k in first.labels})
    feats = {
        kq: {name: np.concatenate([b.feats[kq][name] for b in blocks]) for name in f}
        for kq, f in first.feats.items()
    }
    curves = {}
    for kc in first.curves:
        sq = np.concatenate([b.curves[kc] for b in blocks])[jd.judged[kc[0]]].astype(float)
        curves[kc] = (sq.sum(axis=0), np.full(sq.shape[1], float(sq.shape[0])))
    labels = first.labels
    return Measured(
        exp, labels, feats, jd.judged, jd.reliable, {k: jd.lost(k) for k in labels}, curves, first.t, jd.valid
    )


def seed_ranges(seeds: int) -> list[tuple[int, int]]:
    """Seeds [0, ``seeds``) as ranges ending at 1, 2, 4, 8, … (the last one cut at ``seeds``).

    The first verdicts come after one seed; later ranges grow (fewer blocks, less per-epoch
    overhead), and the ranges of S seeds are those of every larger S up to the cut one, so the
    blocks a shorter reproduction kept serve a longer one.
    """
    out, lo, hi = [], 0, 1
    while lo < seeds:
        out.append((lo, min(hi, seeds)))
        lo, hi = hi, 2 * hi
    return out


@dataclass(frozen=True)
class _Task:
    """Runs [start, stop) of one experiment (``spec``: at S·N runs and the base seed), a block of
    the seeds [``seeds_from``, ``seeds_to``).
    """

    experiment: str
    spec: ExperimentSpec
    start: int
    stop: int
    seeds_from: int
    seeds_to: int
    steps: int  # filter steps (runs × epochs × filters)


def _plan(rep: Reproduction, runs: int, seeds: int, seed: int, stream: bool = True) -> list[_Task]:
    """Every experiment's blocks, seed range by seed range (every experiment's seed 0, then
    seed 1, then seeds 2–3, …: the first verdicts need the first range of every experiment);
    ``stream=False`` (only the final verdicts are wanted): all seeds as one range, in fewer,
    larger blocks (less per-epoch overhead: benchmarks/reproduce_timing.py).

    A seed range whose full arrays would take more than :data:`BLOCK_BYTES` or a tenth of the
    memory budget is split into equal blocks (± 1 run; a block takes about twice its estimate
    while it computes, and two workers compute one each). Large blocks pay the per-epoch Python
    cost of every filter step over more runs. Which block a run is in never changes its draws;
    its last bits may differ (:func:`navlab.experiment.iter_chunks`: BLAS, and a P shared by the
    runs while it can be, as the χ²-KF's and the oracle's), and the blocks of a plan depend only
    on ``stream``, not on the worker count.
    """
    limit = min(BLOCK_BYTES, memory.budget_bytes() / 10)
    sized = []
    for e in rep.experiments:
        spec = e.spec.replace(runs=runs * seeds, seed=seed)
        size = run_size(plan(spec))
        per_run = memory.Size(1, size.epochs, size.n, size.m, size.filters).full()
        sized.append((e.name, spec, int(max(1, limit // max(per_run, 1))), size.epochs * size.filters))
    tasks = []
    for a, b in seed_ranges(seeds) if stream else [(0, seeds)]:
        for name, spec, chunk, per_run_steps in sized:
            lo, hi = a * runs, b * runs
            count = -(-(hi - lo) // chunk)
            edges = [lo + (hi - lo) * i // count for i in range(count + 1)]
            tasks += [
                _Task(name, spec, x, y, a, b, (y - x) * per_run_steps) for x, y in itertools.pairwise(edges)
            ]
    return tasks


def _block_key(rep: Reproduction, t: _Task) -> str:
    """The results store's key of a block: everything that decides its numbers."""
    d = t.spec.to_dict()
    d.pop("runs")
    held = {"quantities": [q.name for q in rep.quantities], "curves": [c.name for c in rep.curves]}
    return key_of(
        {"reproduction": rep.key, "experiment": t.experiment, "spec": d, "runs": [t.start, t.stop]} | held
    )


def _encode(b: _Block) -> tuple[dict[str, Any], dict[str, Array]]:
    """A block as (JSON header, arrays) for the results store (lists keep the filters' order)."""
    head: dict[str, Any] = {"start": b.start, "runs": b.runs, "labels": list(b.labels.items())}
    arrays: dict[str, Array] = {"t": np.asarray(b.t)}
    head["feats"] = [[k, q, name] for (k, q), f in b.feats.items() for name in f]
    for i, (k, q, name) in enumerate(head["feats"]):
        arrays[f"f{i}"] = b.feats[(k, q)][name]
    head["curves"] = [list(kc) for kc in b.curves]
    arrays |= {f"c{i}": v for i, v in enumerate(b.curves.values())}
    head["diverged"] = list(b.diverged)
    arrays |= {f"d{i}": np.asarray(v, dtype=bool) for i, v in enumerate(b.diverged.values())}
    return head, arrays


def _decode(head: dict[str, Any], arrays: dict[str, Array]) -> _Block:
    feats: dict[tuple[str, str], dict[str, Array]] = {}
    for i, (k, q, name) in enumerate(head["feats"]):
        feats.setdefault((k, q), {})[name] = arrays[f"f{i}"]
    return _Block(
        int(head["start"]),
        int(head["runs"]),
        dict(head["labels"]),
        feats,
        {(k, c): arrays[f"c{i}"] for i, (k, c) in enumerate(head["curves"])},
        {k: arrays[f"d{i}"] for i, k in enumerate(head["diverged"])},
        arrays["t"],
    )


def _block_task(key: str, spec: ExperimentSpec, start: int, stop: int) -> _Block:
    """A worker process's task: a block of runs of the registered reproduction ``key``."""
    return _measure_block(REPRODUCTIONS[key], spec, start, stop)


def _registered(rep: Reproduction) -> bool:
    """Whether a worker rebuilds ``rep``'s quantities and curves from the registry by its key
    (an ad-hoc reproduction's functions cannot be sent to another process).
    """
    reg = REPRODUCTIONS.get(rep.key)
    return reg is not None and reg.quantities is rep.quantities and reg.curves is rep.curves


@contextlib.contextmanager
def _single_threaded_blas() -> Iterator[None]:
    """Worker processes started inside get one BLAS/OpenMP thread each (read when numpy loads):
    ``jobs`` processes on ``jobs`` cores, and no threaded LAPACK call waiting for a busy core (a
    stacked (200, 101, 101) solve of the RBF training took 0.33 s with OpenBLAS's threads on this
    2-core machine, 0.03 s with one).
    """
    saved = {v: os.environ.get(v) for v in _BLAS_THREADS}
    os.environ.update(dict.fromkeys(_BLAS_THREADS, "1"))
    try:
        yield
    finally:
        for v, old in saved.items():
            if old is None:
                os.environ.pop(v, None)
            else:
                os.environ[v] = old


def _compute(
    rep: Reproduction,
    tasks: Sequence[_Task],
    jobs: int,
    keep: Callable[[int, _Block], None],
    should_stop: Callable[[], bool] | None,
    tick: Callable[[], None] | None,
) -> Iterator[tuple[int, _Block]]:
    """(index in ``tasks``, block) as each block finishes: in ``jobs`` worker processes when
    there are several blocks and enough work to pay for starting them (each imports
    navlab), else in this process, one after the other.

    ``should_stop()`` is asked between blocks (in this process) or every :data:`POLL_S` while
    waiting on the workers, when ``tick()`` is also called (the app handles a Stop there). On
    stop, an error or when the caller closes this generator (a closed browser session), the blocks
    not yet started are cancelled and the worker processes killed at once: the work in flight is
    lost, the blocks that finished meanwhile go to ``keep``.
    """
    if _pool_size(rep, tasks, jobs) == 1:
        for i, t in enumerate(tasks):
            if should_stop is not None and should_stop():
                return
            yield i, _measure_block(rep, t.spec, t.start, t.stop)
        return
    if should_stop is not None and should_stop():
        return
    ctx = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(_pool_size(rep, tasks, jobs), mp_context=ctx)
    futs: dict[Future, int] = {}
    handed: set[Future] = set()
    try:
        with _single_threaded_blas():  # the workers start at the first submissions
            futs = {
                pool.submit(_block_task, rep.key, t.spec, t.start, t.stop): i for i, t in enumerate(tasks)
            }
        pending = set(futs)
        while pending:
            if should_stop is not None and should_stop():
                return
            finished, pending = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
            if not finished and tick is not None:
                tick()
            for f in sorted(finished, key=futs.__getitem__):  # in the plan's order
                handed.add(f)
                yield futs[f], f.result()
    except BrokenProcessPool:
        raise NavlabError(
            f"a worker process of the reproduction died (out of memory?): retry with --jobs 1 or {JOBS_ENV}=1"
        ) from None
    finally:
        for f, i in futs.items():
            if f not in handed and f.done() and not f.cancelled() and f.exception() is None:
                keep(i, f.result())
        # stopped: kill the workers (the pool then fails the blocks not done; cancelling them
        # first would crash its manager thread on Python 3.11, which fails cancelled ones too)
        stopped = any(not f.done() for f in futs)
        if stopped:
            _terminate(pool)
        pool.shutdown(wait=not stopped)


def _pool_size(rep: Reproduction, tasks: Sequence[_Task], jobs: int) -> int:
    """Worker processes for ``tasks`` (1: this process): several blocks, and enough filter steps
    to pay for starting the workers.
    """
    if jobs == 1 or len(tasks) < 2 or sum(t.steps for t in tasks) < POOL_MIN_STEPS or not _registered(rep):
        return 1
    return min(jobs, len(tasks))


def workers(
    rep: Reproduction, runs: int, seeds: int, seed: int, jobs: int | None = None, stream: bool = True
) -> int:
    """The processes a reproduction computes in (1: the calling process; blocks found in a
    results store are not computed, so a resumed one may use fewer).
    """
    jobs = default_jobs() if jobs is None else check_jobs(jobs)
    return _pool_size(rep, _plan(rep, runs, seeds, seed, stream), jobs)


def _terminate(pool: ProcessPoolExecutor) -> None:
    """Kill ``pool``'s worker processes now (their blocks in flight are lost)."""
    kill = getattr(pool, "terminate_workers", None)  # Python ≥ 3.14
    if callable(kill):
        kill()
        return
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        p.terminate()
    for p in procs:
        p.join(timeout=10)


def default_jobs() -> int:
    """Worker processes of a reproduction: ``NAVLAB_JOBS``, else the cores this process may use."""
    env = os.environ.get(JOBS_ENV, "").strip()
    if not env:
        from navlab.cluster import cpu_count

        return cpu_count()
    return check_jobs(env, JOBS_ENV)


def check_jobs(value: Any, name: str = "--jobs") -> int:
    """``value`` as a number of worker processes (a whole number ≥ 1), else NavlabError."""
    try:
        jobs = int(value)
    except (TypeError, ValueError):
        jobs = 0
    if isinstance(value, bool) or jobs < 1 or str(jobs) != str(value).strip():
        raise NavlabError(f"{name} must be a whole number ≥ 1 (worker processes), got {value!r}")
    from navlab.cluster import cpu_count

    most = max(8, 4 * cpu_count())  # more cannot go faster; each worker holds navlab in memory
    if jobs > most:
        raise NavlabError(
            f"{name} {jobs}: at most {most} worker processes on this machine ({cpu_count()} cores); "
            "more cannot go faster"
        )
    return jobs


def _quantity(rep: Reproduction, name: str) -> Quantity:
    for q in rep.quantities:
        if q.name == name:
            return q
    raise KeyError(name)


class _Evaluator:
    def __init__(self, rep: Reproduction, measured: dict[str, Measured], runs: int, seeds: int, seed: int):
        self.rep, self.m, self.N, self.S, self.seed = rep, measured, runs, seeds, seed

    def sets(self) -> list[Array]:
        total = self.N * self.S
        idx = np.arange(total)
        return [(idx >= s * self.N) & (idx < (s + 1) * self.N) for s in range(self.S)]

    def estimator(self, ref: Ref, quantity: str, runs: Array) -> S.Estimator:
        f = self.m[ref.experiment].feats[(ref.filter, quantity)]
        return _quantity(self.rep, quantity).make({k: v[runs] for k, v in f.items()})

    def judged(self, *refs: Ref) -> Array:
        mask = np.ones(self.N * self.S, dtype=bool)
        for r in refs:
            mask &= self.m[r.experiment].judged[r.filter]
        return mask

    def per_set(self, ref: Ref, quantity: str) -> Array:
        jd = self.judged(ref)
        vals = [
            self.estimator(ref, quantity, s & jd).point() if (s & jd).any() else np.nan for s in self.sets()
        ]
        return np.asarray(vals, dtype=float)

    def pooled(self, ref: Ref, quantity: str) -> S.Estimate:
        runs = self.judged(ref)
        n = int(runs.sum())
        if n == 0:
            return S.Estimate(float("nan"), note="no run to judge")
        return S.Resampler(n, self.seed).estimate(self.estimator(ref, quantity, runs))

    def compare(self, a: Ref, b: Ref, quantity: str, relative: bool = False) -> S.Comparison | None:
        got = self.compare_both(a, b, quantity, absolute=not relative, relative=relative)
        return None if got is None else got[relative]

    def compare_both(
        self, a: Ref, b: Ref, quantity: str, absolute: bool = True, relative: bool = True
    ) -> tuple[S.Comparison | None, S.Comparison | None] | None:
        """(a − b, (a − b)/b) paired on the same resamples (the second one costs little more: the
        estimators' resampled values are computed once), under the loss rule of
        navlab.metrics.LOSS_RULE: over every run, a run lost by one of the two scored as the
        pair's worst (navlab.stats.with_losses); over the runs judged for both where neither lost
        a run.
        """
        lost_a, lost_b = self.lost(a), self.lost(b)
        runs = np.ones(self.N * self.S, dtype=bool) if lost_a.any() or lost_b.any() else self.judged(a, b)
        n = int(runs.sum())
        if n == 0:
            return None
        rs = S.Resampler(n, self.seed)
        ea, eb = self.estimator(a, quantity, runs), self.estimator(b, quantity, runs)
        if lost_a.any() or lost_b.any():
            sign = 1 if _quantity(self.rep, quantity).lower_is_better else -1
            ea, eb = S.with_losses(ea, eb, lost_a, lost_b, sign)
        return (rs.compare(ea, eb) if absolute else None, rs.compare(ea, eb, True) if relative else None)

    def lost(self, r: Ref) -> Array:
        """The runs filter ``r`` lost (diverged), (S·N,) bool."""
        valid = self.m[r.experiment].valid.get(r.filter)
        return np.zeros(self.N * self.S, dtype=bool) if valid is None else ~valid

    def label(self, r: Ref, *others: Ref) -> str:
        """The filter's name, with its experiment where ``others`` span several experiments."""
        several = len({x.experiment for x in (r, *others)}) > 1
        return f"{self.name(r)} ({r.experiment})" if several else self.name(r)

    def reliability_note(self, *refs: Ref) -> str:
        notes = []
        for r in refs:
            m = self.m[r.experiment]
            if m.lost[r.filter]:
                total = self.N * self.S
                rel = "" if m.reliable[r.filter] else ", more than 5 %: ranks below"
                notes.append(f"{self.name(r)} diverges in {m.lost[r.filter]} of {total} runs{rel}")
        return "; ".join(notes)

    def name(self, r: Ref) -> str:
        return self.rep.name(r.filter)


def _range(v: Array) -> tuple[float, float]:
    v = v[np.isfinite(v)]
    if not v.size:
        return float("nan"), float("nan")
    lo, hi = np.quantile(v, [0.025, 0.975])
    return float(lo), float(hi)


def _number_verdict(mean: S.Estimate, paper: float) -> str:
    if not np.isfinite(mean.value):
        return "inconclusive"
    band = TOLERANCE * abs(paper)
    if abs(mean.value - paper) <= band:
        return "reproduced"
    if mean.has_ci and (mean.lo > paper + band or mean.hi < paper - band):
        return "contradicted"
    return "inconclusive"


def _row(claim: Claim, kind: str, **kw) -> dict:
    base = dict(
        claim=claim.id,
        kind=kind,
        text=claim.text,
        paper=np.nan,
        mean=np.nan,
        ci_lo=np.nan,
        ci_hi=np.nan,
        range_lo=np.nan,
        range_hi=np.nan,
        unit="",
        seeds=np.nan,
        runs_per_seed=np.nan,
        share_of_seeds_holding=np.nan,
        p_value=np.nan,
        p_bound="",  # "<": p_value is a bound (at the bootstrap's floor)
        verdict="",
        note=claim.note,
        where=claim.where,
        quote=claim.quote,
        chosen=claim.chosen,
    )
    base.update(kw)
    return base


def _join(*parts: str) -> str:
    return "; ".join(p for p in parts if p)


def _judge_number(ev: _Evaluator, c: Number, unit: str) -> dict:
    vals = ev.per_set(c.ref, c.quantity)
    mean = S.mean_ci(vals)
    lo, hi = _range(vals)
    inside = lo <= c.paper <= hi
    notes = [c.note, f"paper value inside the per-seed range: {'yes' if inside else 'no'}"]
    floor = _oracle_floor(ev, c.ref, c.quantity)
    if floor is not None and c.paper < floor:
        notes.append(
            f"the paper's {c.paper:g} lies below the oracle KF's {S.sig3(floor)} (the MMSE floor of "
            "navlab's setup): the claim is about a different setup"
        )
    notes.append(ev.reliability_note(c.ref))
    return _row(
        c,
        "number",
        paper=c.paper,
        mean=mean.value,
        ci_lo=mean.lo,
        ci_hi=mean.hi,
        range_lo=lo,
        range_hi=hi,
        unit=unit,
        seeds=ev.S,
        runs_per_seed=ev.N,
        share_of_seeds_holding=float(np.mean(np.abs(vals - c.paper) <= TOLERANCE * abs(c.paper))),
        verdict=_number_verdict(mean, c.paper),
        note=_join(*notes),
    )


def _oracle_floor(ev: _Evaluator, ref: Ref, quantity: str) -> float | None:
    m = ev.m[ref.experiment]
    if ("oracle-kf", quantity) not in m.feats or ref.filter == "oracle-kf":
        return None
    v = ev.per_set(Ref(ref.experiment, "oracle-kf"), quantity)
    return float(np.nanmean(v)) if np.isfinite(v).any() else None


def _judge_bound(ev: _Evaluator, c: Bound, unit: str) -> dict:
    vals = ev.per_set(c.ref, c.quantity)
    mean = S.mean_ci(vals)
    lo, hi = _range(vals)
    side = vals > c.bound if c.above else vals < c.bound
    if not mean.has_ci:
        verdict = "inconclusive"
    elif (mean.lo > c.bound) if c.above else (mean.hi < c.bound):
        verdict = "reproduced"
    elif (mean.hi < c.bound) if c.above else (mean.lo > c.bound):
        verdict = "contradicted"
    else:
        verdict = "inconclusive"
    return _row(
        c,
        "bound",
        paper=c.bound,
        mean=mean.value,
        ci_lo=mean.lo,
        ci_hi=mean.hi,
        range_lo=lo,
        range_hi=hi,
        unit=unit,
        seeds=ev.S,
        runs_per_seed=ev.N,
        share_of_seeds_holding=float(np.mean(side[np.isfinite(vals)])) if np.isfinite(vals).any() else np.nan,
        verdict=verdict,
        note=_join(
            c.note, f"paper: {'above' if c.above else 'below'} {c.bound:g} {unit}", ev.reliability_note(c.ref)
        ),
    )


def _judge_ranking(ev: _Evaluator, c: Ranking, unit: str) -> dict:
    q = _quantity(ev.rep, c.quantity)
    # c.worst: the claim is that c.better is worse than each of c.than (the sign turns round)
    sign = (1.0 if q.lower_is_better else -1.0) * (-1.0 if c.worst else 1.0)
    # the share of sets on which the claim holds (point estimates of each set)
    mine = ev.per_set(c.better, c.quantity)
    others = np.array([ev.per_set(r, c.quantity) for r in c.than])
    holds = np.all(sign * (mine[None] - others) < 0, axis=0)
    share = float(np.mean(holds))  # a set on which the filter kept no run does not hold
    # the pooled paired test, Holm over the competitors; a filter diverging in more than 5 % of
    # the runs loses to a reliable one whatever its numbers
    both = {r: ev.compare_both(c.better, r, c.quantity) for r in c.than}
    comps = {r: (b[0] if b is not None else None) for r, b in both.items()}
    refs = (c.better, *c.than)
    evidence = [
        _evidence(
            c, "ranking", ev.label(c.better, *refs), ev.label(r, *refs), b[1], np.nan, q.lower_is_better
        )
        for r, b in both.items()
        if b is not None
    ]
    adj, adj_bound = S.holm_bounds(
        {str(i): (cm.p_value if cm is not None else np.nan) for i, cm in enumerate(comps.values())},
        {str(i): bool(cm is not None and cm.at_floor) for i, cm in enumerate(comps.values())},
    )
    better, worse, parts = {}, {}, []
    for i, (r, cm) in enumerate(comps.items()):
        rel_a = ev.m[c.better.experiment].reliable[c.better.filter]
        rel_b = ev.m[r.experiment].reliable[r.filter]
        p = adj[str(i)]
        if rel_b and not rel_a:
            (better if c.worst else worse)[r] = 0.0
        elif rel_a and not rel_b:
            (worse if c.worst else better)[r] = 0.0
        elif cm is not None and np.isfinite(p) and p < S.ALPHA:
            (better if sign * cm.value < 0 else worse)[r] = p
        if cm is not None:
            parts.append(
                f"vs {ev.name(r)}: Δ {S.sig3(cm.value)} [{S.sig3(cm.lo)}, {S.sig3(cm.hi)}] {unit}, "
                f"Holm {S.format_p(p, adj_bound[str(i)])}"
            )
    finite = {k: v for k, v in adj.items() if np.isfinite(v)}
    keys = {r: str(i) for i, r in enumerate(comps)}
    if len(better) == len(c.than):
        pick = max(finite, key=finite.get, default=None)  # every comparison must hold
        verdict = "reproduced"
    elif worse:
        forced = any(v == 0.0 for v in worse.values())  # a filter diverging in > 5 %: p 0
        tested = [keys[r] for r in worse if keys[r] in finite]
        pick = None if forced else min(tested, key=finite.get, default=None)
        verdict = "contradicted"  # the clearest counterexample
    else:
        pick = max(finite, key=finite.get, default=None)
        verdict = "inconclusive"
    p_value = finite[pick] if pick is not None else (0.0 if verdict == "contradicted" else np.nan)
    p_bound = "<" if pick is not None and adj_bound[pick] else ""
    first = comps[c.than[0]] if len(c.than) == 1 else None
    return _row(
        c,
        "ranking",
        mean=first.value if first is not None else np.nan,
        ci_lo=first.lo if first is not None else np.nan,
        ci_hi=first.hi if first is not None else np.nan,
        unit=unit,
        seeds=ev.S,
        runs_per_seed=ev.N,
        share_of_seeds_holding=share,
        p_value=p_value,
        p_bound=p_bound,
        verdict=verdict,
        note=_join(c.note, "; ".join(parts), ev.reliability_note(c.better, *c.than)),
        evidence=evidence,
    )


# a qualitative claim's evidence: the paired (a − b)/b of the claimed filter a against each
# competitor b (a ranking), or of each filter against the best (a "close" claim, band ±within)
EVIDENCE_COLUMNS = ("claim", "kind", "a", "b", "quantity", "rel", "rel_lo", "rel_hi", "within", "lower")


def _evidence(
    c: Claim, kind: str, a: str, b: str, cm: S.Comparison, within: float, lower_is_better: bool
) -> dict:
    """One paired relative difference (a − b)/b a qualitative claim rests on, with its interval."""
    values = (c.id, kind, a, b, c.quantity, cm.value, cm.lo, cm.hi, within, lower_is_better)
    return dict(zip(EVIDENCE_COLUMNS, values, strict=True))


def _judge_margin(ev: _Evaluator, c: Margin, unit: str) -> dict:
    cm = ev.compare(c.a, c.b, c.quantity, relative=True)
    va, vb = ev.per_set(c.a, c.quantity), ev.per_set(c.b, c.quantity)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = (va - vb) / vb
    off = 1.0 if c.as_ratio else 0.0
    paper = c.paper
    per = rel + off
    lo, hi = _range(per)
    if cm is None:
        return _row(c, "margin", paper=paper, verdict="inconclusive", note=c.note)
    est = S.Estimate(cm.value + off, cm.lo + off, cm.hi + off, cm.method)
    return _row(
        c,
        "margin",
        paper=paper,
        mean=est.value,
        ci_lo=est.lo,
        ci_hi=est.hi,
        range_lo=lo,
        range_hi=hi,
        unit="ratio" if c.as_ratio else "relative",
        seeds=ev.S,
        runs_per_seed=ev.N,
        share_of_seeds_holding=float(np.mean(np.abs(per - paper) <= TOLERANCE * abs(paper))),
        p_value=cm.p_value,
        p_bound="<" if cm.at_floor else "",
        verdict=_number_verdict(est, paper),
        note=_join(
            c.note,
            f"paired over {cm.n_runs} runs pooled; paper value inside the per-seed range: "
            f"{'yes' if lo <= paper <= hi else 'no'}",
            ev.reliability_note(c.a, c.b),
        ),
    )


def _judge_close(ev: _Evaluator, c: Close, unit: str) -> dict:
    q = _quantity(ev.rep, c.quantity)
    sign = 1.0 if q.lower_is_better else -1.0
    vals = np.array([ev.per_set(r, c.quantity) for r in c.refs])  # (refs, sets)
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = np.nanmax(vals, axis=0) / np.nanmin(vals, axis=0) - 1.0
    pooled = [ev.pooled(r, c.quantity).value for r in c.refs]
    best = c.refs[int(np.nanargmin(sign * np.asarray(pooled)))]
    inside, outside, parts, evidence = 0, 0, [], []
    for r in c.refs:
        if r == best:
            continue
        cm = ev.compare(r, best, c.quantity, relative=True)
        if cm is not None and np.isfinite(cm.value):
            a, b = ev.label(r, *c.refs), ev.label(best, *c.refs)
            evidence.append(_evidence(c, "close", a, b, cm, c.within, q.lower_is_better))
        if cm is None or not np.isfinite(cm.lo):
            continue
        inside += -c.within <= cm.lo and cm.hi <= c.within
        outside += cm.lo > c.within or cm.hi < -c.within
        parts.append(
            f"{ev.name(r)} vs {ev.name(best)}: {100 * cm.value:+.1f} % "
            f"[{100 * cm.lo:+.1f}, {100 * cm.hi:+.1f}]"
        )
    n = len(c.refs) - 1
    verdict = "reproduced" if inside == n else ("contradicted" if outside else "inconclusive")
    lo, hi = _range(spread)
    return _row(
        c,
        "close",
        paper=c.within,
        mean=float(np.nanmean(spread)),
        range_lo=lo,
        range_hi=hi,
        unit="relative spread",
        seeds=ev.S,
        runs_per_seed=ev.N,
        share_of_seeds_holding=float(np.mean(spread[np.isfinite(spread)] <= c.within)),
        verdict=verdict,
        note=_join(
            c.note,
            f"'close' read as every filter within ±{100 * c.within:g} % of the best ({ev.name(best)})",
            "; ".join(parts),
            ev.reliability_note(*c.refs),
        ),
        evidence=evidence,
    )


def evaluate(rep: Reproduction, *args: Any, **kw: Any) -> Outcome:
    """Run ``seeds`` sets of ``runs`` runs of every experiment and judge every claim: the last
    :class:`Outcome` of :func:`iter_evaluate` (the same arguments). ``stream`` None: in the
    page's seed ranges with a results store (its blocks are those the page keeps), else in one.
    """
    last = None
    if kw.get("stream") is None:
        kw["stream"] = kw.get("store") is not None
    for o in iter_evaluate(rep, *args, **kw):
        last = o
    assert last is not None
    return last


def iter_evaluate(
    rep: Reproduction,
    runs: int | None = None,
    seeds: int = DEFAULT_SEEDS,
    seed: int = 1,
    *,
    on_progress: Callable[[int, int], None] | None = None,
    jobs: int | None = None,
    store: Store | None = None,
    should_stop: Callable[[], bool] | None = None,
    tick: Callable[[], None] | None = None,
    stream: bool = True,
) -> Iterator[Outcome]:
    """The verdicts as the seeds finish: an :class:`Outcome` of the first k seeds every time k
    grows (seed ranges of :func:`seed_ranges`), the last one of all ``seeds`` seeds. The outcome
    of k seeds is exactly that of a k-seed reproduction.

    ``jobs`` worker processes compute the blocks of runs (default :func:`default_jobs`); the
    numbers are the same for any ``jobs``. ``store`` (:class:`navlab.store.Store`) keeps every
    finished block of a registered reproduction, so a stopped, abandoned or repeated one computes
    only what is missing. ``on_progress(runs done, runs in all)``; ``should_stop`` and ``tick`` as
    in :func:`_compute` (``should_stop`` always true: what the store holds, nothing computed).
    Closing this generator stops the work (worker processes included) at once. ``stream=False``:
    one seed range (:func:`_plan`), so only the outcome of all seeds is yielded.
    """
    runs = rep.default_runs if runs is None else runs
    jobs = default_jobs() if jobs is None else check_jobs(jobs)
    for name, v, lo in (("runs", runs, 1), ("seeds", seeds, 1)):
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise NavlabError(f"--{name} must be a whole number ≥ {lo}, got {v!r}")
    if runs * seeds > MAX_RUNS:
        raise NavlabError(
            f"--seeds {seeds} × --runs {runs} = {runs * seeds} runs per experiment, more than {MAX_RUNS}; "
            "use fewer seeds or runs"
        )
    tasks = _plan(rep, runs, seeds, seed, stream)
    keyed = store is not None and store.root is not None and _registered(rep)
    blocks: dict[int, _Block] = {}
    if keyed:
        for i, t in enumerate(tasks):
            hit = store.get(_block_key(rep, t))
            if hit is not None:
                blocks[i] = _decode(*hit)
    total = runs * seeds * len(rep.experiments)

    def keep(i: int, blk: _Block) -> None:
        blocks[i] = blk
        if keyed:
            store.put(_block_key(rep, tasks[i]), *_encode(blk))

    def judged_seeds() -> int:
        """The seeds whose blocks have all finished, counted from seed 0."""
        return min((t.seeds_from for i, t in enumerate(tasks) if i not in blocks), default=seeds)

    def progress() -> None:
        if on_progress is not None:
            on_progress(sum(b.runs for b in blocks.values()), total)

    def outcome(k: int) -> Outcome:
        upto = {t.experiment: [] for t in tasks}
        for i, t in enumerate(tasks):
            if t.seeds_to <= k:
                upto[t.experiment].append(blocks[i])
        return _judge(
            rep, {e.name: _assemble(e, upto[e.name]) for e in rep.experiments}, runs, k, seed, seeds
        )

    progress()
    shown = judged_seeds()
    if shown:
        yield outcome(shown)
    todo = [i for i in range(len(tasks)) if i not in blocks]
    work = _compute(rep, [tasks[i] for i in todo], jobs, lambda j, b: keep(todo[j], b), should_stop, tick)
    with contextlib.closing(work) as done:
        for j, blk in done:
            keep(todo[j], blk)
            progress()
            k = judged_seeds()
            if k > shown:
                shown = k
                yield outcome(k)


def _judge(
    rep: Reproduction, measured: dict[str, Measured], runs: int, seeds: int, seed: int, asked: int
) -> Outcome:
    """Every claim judged on the first ``seeds`` seeds."""
    ev = _Evaluator(rep, measured, runs, seeds, seed)
    rows = [_judge_claim(ev, c) for c in rep.claims]
    evidence = [e for r in rows for e in r.pop("evidence", [])]
    return Outcome(
        rep,
        pd.DataFrame(rows),
        pd.DataFrame(evidence, columns=list(EVIDENCE_COLUMNS)),
        _curves(rep, measured),
        seeds,
        runs,
        seed,
        asked,
        ev,
    )


def claim_refs(c: Claim) -> tuple[Ref, ...]:
    """The (experiment, filter) pairs a claim is judged on."""
    if isinstance(c, Number | Bound):
        return (c.ref,)
    if isinstance(c, Ranking):
        return (c.better, *c.than)
    if isinstance(c, Margin):
        return (c.a, c.b)
    if isinstance(c, Close):
        return c.refs
    return ()


def _judge_one(ev: _Evaluator, c: Claim) -> dict:
    """The row of one claim under one setting (its verdict by its form's rule)."""
    if isinstance(c, Untested):
        return _row(c, "untested", verdict="not testable", note=_join(f"not testable: {c.reason}", c.note))
    unit = _quantity(ev.rep, c.quantity).unit
    judges = {Number: _judge_number, Bound: _judge_bound, Ranking: _judge_ranking, Close: _judge_close}
    return judges.get(type(c), _judge_margin)(ev, c, unit)


def failed_reconstruction(ev: _Evaluator, c: Claim) -> str:
    """Why the reconstruction a claim needs failed ('' if it did not): a filter of ``c.needs``
    (navlab's reconstruction of equations the paper's text lost) that diverges in more than 5 % of
    the runs (navlab.metrics' reliability rule) cannot stand for the paper's algorithm.
    """
    bad = []
    for r in claim_refs(c):
        if r.filter in c.needs and not ev.m[r.experiment].reliable[r.filter]:
            bad.append(f"{ev.name(r)} diverges in {ev.m[r.experiment].lost[r.filter]} of {ev.N * ev.S} runs")
    return "; ".join(dict.fromkeys(bad))


def combine(verdict: str, failed: str, alternatives: Sequence[tuple[Alternative, str]]) -> str:
    """The row's verdict from the verdict under navlab's setting, a failed reconstruction ('' if
    none) and the verdicts under the claim's documented alternatives (docs/STATISTICS.md §4):
    *not testable* when the reconstruction the claim needs failed; *setup-dependent* when the
    verdict is decisive (reproduced or contradicted) and a deciding alternative gives the other
    decisive verdict; else the verdict under navlab's setting.
    """
    if failed:
        return "not testable"
    if verdict in DECISIVE:
        for alt, v in alternatives:
            if alt.decides and v in DECISIVE and v != verdict:
                return "setup-dependent"
    return verdict


def _judge_claim(ev: _Evaluator, c: Claim) -> dict:
    """A claim's row: judged under navlab's setting, under each documented alternative, and
    combined (:func:`combine`); the note says what every alternative gave.
    """
    row = _judge_one(ev, c)
    alts = []
    for alt in c.alternatives:
        r = _judge_one(ev, alt.claim)
        r.pop("evidence", None)
        alts.append((alt, r))
    failed = failed_reconstruction(ev, c) if c.needs else ""
    primary = row["verdict"]
    verdict = combine(primary, failed, [(a, r["verdict"]) for a, r in alts])
    parts = []
    if failed:
        parts.append(
            f"not testable: the reconstruction this claim needs fails ({failed}); what the failed "
            f"reconstruction gives would read '{primary}'"
        )
    elif verdict != primary:
        parts.append(f"{verdict}: '{primary}' under navlab's setting, another verdict under an alternative")
    if c.chosen:
        parts.append(f"‡ {c.chosen}")
    for a, r in alts:
        tag = "" if a.decides else " (shown only: not the paper's)"
        parts.append(f"alternative — {a.label}{tag}: {r['verdict']} ({_alt_value(r)})")
    row.update(
        verdict=verdict,
        verdict_navlab=primary,
        alternatives="; ".join(f"{a.label}: {r['verdict']}" for a, r in alts),
        note=_join(*parts, row["note"]),
    )
    return row


def _alt_value(r: dict) -> str:
    """What an alternative's row found, briefly."""
    if r["kind"] == "untested":
        return "not testable"
    if r["kind"] in ("ranking",):
        if np.isfinite(r["mean"]):
            return f"Δ {S.sig3(r['mean'])} [{S.sig3(r['ci_lo'])}, {S.sig3(r['ci_hi'])}] {r['unit']}".strip()
        return r["note"].split("; ")[0] if r["note"] else "see the paired tests"
    if r["kind"] == "close":
        return f"spread {100 * r['mean']:.1f} %" if np.isfinite(r["mean"]) else "no value"
    if r["kind"] == "margin" and r["unit"] == "relative":
        return f"{100 * r['mean']:+.1f} % [{100 * r['ci_lo']:+.1f}, {100 * r['ci_hi']:+.1f}]"
    if np.isfinite(r["ci_lo"]):
        return f"{S.sig3(r['mean'])} [{S.sig3(r['ci_lo'])}, {S.sig3(r['ci_hi'])}] {r['unit']}".strip()
    return f"{S.sig3(r['mean'])} {r['unit']}".strip()


def _readings(rep: Reproduction, ev: _Evaluator) -> pd.DataFrame:
    """Every quantity of every filter of every experiment: pooled over all judged runs with its
    interval, the mean and range over the sets, and the paper's number where a claim gives one.
    """
    papers = {
        (c.ref.experiment, c.ref.filter, c.quantity): c.paper for c in rep.claims if isinstance(c, Number)
    }
    rows = []
    for name, m in ev.m.items():
        for key in m.labels:
            for q in rep.quantities:
                if (key, q.name) not in m.feats:
                    continue
                ref = Ref(name, key)
                pooled = ev.pooled(ref, q.name)
                vals = ev.per_set(ref, q.name)
                lo, hi = _range(vals)
                rows.append(
                    dict(
                        experiment=name,
                        filter=key,
                        label=rep.name(key),
                        quantity=q.name,
                        value=pooled.value,
                        ci_lo=pooled.lo,
                        ci_hi=pooled.hi,
                        seed_mean=float(np.nanmean(vals)) if np.isfinite(vals).any() else np.nan,
                        range_lo=lo,
                        range_hi=hi,
                        paper=papers.get((name, key, q.name), np.nan),
                        unit=q.unit,
                        runs_used=int(ev.judged(ref).sum()),
                        diverged=m.lost[key],
                        note=_join(q.help, rep.notes.get(q.name, ""), rep.notes.get(f"{key}:{q.name}", "")),
                    )
                )
    return pd.DataFrame(rows)


def _curves(rep: Reproduction, measured: dict[str, Measured]) -> dict[str, pd.DataFrame]:
    out = {}
    for name, m in measured.items():
        for c in rep.curves:
            tab: dict[str, Array] = {"t_s": m.t}
            for key in m.labels:
                if (key, c.name) in m.curves:
                    s, n = m.curves[(key, c.name)]
                    with np.errstate(divide="ignore", invalid="ignore"):
                        tab[f"{key}_rmse_{c.name}_{c.unit.replace('/', 'p')}"] = np.sqrt(s / n)
            out[f"{rep.key}_{name}_rmse_{c.name}.csv"] = pd.DataFrame(tab)
    return out


def replace_spec(rep: Reproduction, **changes: Any) -> Reproduction:
    """The reproduction with every experiment's spec changed (e.g. epochs for a quick test)."""
    exps = tuple(dataclasses.replace(e, spec=e.spec.replace(**changes)) for e in rep.experiments)
    return dataclasses.replace(rep, experiments=exps)
