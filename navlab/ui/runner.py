"""Cached and streaming experiment runners for the pages.

* :class:`ResultStore` — one process-wide LRU of finished :class:`~navlab.experiment.Results`,
  keyed by the spec's JSON and bounded by entry count and bytes (``st.cache_resource`` holds it,
  so every session shares it and a shared link whose run is cached shows at once). Results are
  shared, not copied: nothing may mutate them. An entry nobody has asked for in
  ``NAVLAB_RESULT_TTL`` seconds (default 900) is dropped by a background sweep, which also removes
  the closed browser sessions Streamlit keeps for a reconnect once their window has passed, and
  gives the freed heap back to the operating system: the server shrinks again after a busy spell.
* :func:`run_live` — run a spec in a few chunks of Monte Carlo runs, calling ``render`` with the
  accumulated results after each chunk (progress bar, optional Stop button); a run that is short
  or overhead-bound by this process's experience is one chunk (see :func:`iter_chunks`). A rerun that
  interrupts it (a view control, Stop) keeps the partial results in the session and the next run
  of the same spec resumes from them: run r always draws from its own seed, so chunking never
  changes the numbers.
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import logging
import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import streamlit as st

from navlab import memory
from navlab.errors import NavlabError
from navlab.experiment import (
    ExperimentSpec,
    FilterRun,
    Plan,
    Results,
    as_plan,
    iter_experiment,
    plan,
    run_size,
)

log = logging.getLogger(__name__)
PARTIAL_KEY = "_navlab_partial"  # session: {page: (spec_json, Results)}
PENDING_KEY = "_navlab_pending"  # session: {page: spec_json} — a run the user asked for


def _nbytes(obj: Any, depth: int = 0) -> int:
    if isinstance(obj, np.ndarray):
        return int(obj.nbytes)
    if depth > 4:
        return 0
    if isinstance(obj, dict):
        return sum(_nbytes(v, depth + 1) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(_nbytes(v, depth + 1) for v in obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return sum(_nbytes(getattr(obj, f.name), depth + 1) for f in dataclasses.fields(obj))
    return 0


def results_nbytes(res: Results) -> int:
    """Approximate memory held by a Results (its numpy arrays)."""
    return _nbytes(res.data) + sum(_nbytes(fr) for fr in res.runs.values())


RESULT_TTL_ENV = "NAVLAB_RESULT_TTL"
DEFAULT_RESULT_TTL_S = 900.0


def result_ttl_s(raw: str | None = None) -> float | None:
    """Seconds an unused result stays in the store (``NAVLAB_RESULT_TTL``; ``off`` keeps results
    until the store's bounds push them out).
    """
    raw = os.environ.get(RESULT_TTL_ENV) if raw is None else raw
    if raw is None or not raw.strip():
        return DEFAULT_RESULT_TTL_S
    if raw.strip().lower() in ("off", "none", "never"):
        return None
    try:
        ttl = float(raw)
    except ValueError:
        ttl = float("nan")
    if not (np.isfinite(ttl) and ttl > 0):
        raise NavlabError(
            f"{RESULT_TTL_ENV}={raw!r} is not a positive number of seconds: set it to e.g. 900, or to off"
        )
    return ttl


class ResultStore:
    """Thread-safe LRU of finished results keyed by spec JSON, bounded by entries and bytes, and
    by idle time: :meth:`expire` drops the entries unused for ``ttl_s`` seconds (None: never).

    ``clock`` is injectable so that the tests can move time without waiting.
    """

    def __init__(
        self,
        max_entries: int = 32,
        max_bytes: int = 768 * 2**20,
        ttl_s: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.max_entries, self.max_bytes, self.ttl_s, self.clock = max_entries, max_bytes, ttl_s, clock
        self._d: OrderedDict[str, tuple[Results, int, float]] = OrderedDict()  # (res, bytes, last use)
        self._lock = threading.Lock()

    def get(self, key: str) -> Results | None:
        with self._lock:
            hit = self._d.get(key)
            if hit is None:
                return None
            self._d[key] = (hit[0], hit[1], self.clock())
            self._d.move_to_end(key)
            return hit[0]

    def put(self, key: str, res: Results) -> None:
        size = results_nbytes(res)
        with self._lock:
            self._d[key] = (res, size, self.clock())
            self._d.move_to_end(key)
            total = self.nbytes_locked()
            while len(self._d) > 1 and (len(self._d) > self.max_entries or total > self.max_bytes):
                _, (_, s, _) = self._d.popitem(last=False)
                total -= s

    def expire(self) -> int:
        """Drop the entries unused for ``ttl_s`` seconds; return how many were dropped."""
        if self.ttl_s is None:
            return 0
        with self._lock:
            cutoff = self.clock() - self.ttl_s
            old = [k for k, (_, _, used) in self._d.items() if used <= cutoff]
            for k in old:
                del self._d[k]
        return len(old)

    def nbytes_locked(self) -> int:
        return sum(s for _, s, _ in self._d.values())

    @property
    def nbytes(self) -> int:
        with self._lock:
            return self.nbytes_locked()

    def __len__(self) -> int:
        return len(self._d)

    def clear(self) -> None:
        with self._lock:
            self._d.clear()


def reap_closed_sessions() -> int:
    """Remove the closed browser sessions whose reconnect window has passed; return how many.

    Streamlit keeps a closed session for ``server.disconnectedSessionTTL`` (120 s) in case the
    browser reconnects, in a TTL cache that removes expired entries only when it is next written
    to — by the next visitor's disconnect. Until then a closed session's state (its figures and
    the download buttons' callbacks, which hold its results) stays in memory: measured, 6 closed
    Compare sessions kept ≈ 125 MB with no visitor. This calls that cache's ``expire()`` (internal to
    Streamlit 1.67: :func:`streamlit.runtime.Runtime.instance` → session manager → session
    storage); where Streamlit differs it does nothing.
    """
    try:
        from streamlit.runtime import Runtime

        if not Runtime.exists():
            return 0
        mgr = Runtime.instance()._session_mgr
        expire = getattr(getattr(mgr._session_storage, "_cache", None), "expire", None)
        if not callable(expire):
            return 0
        with getattr(mgr, "_storage_lock", contextlib.nullcontext()):  # the cache is not thread-safe
            return len(expire())
    except Exception:  # a Streamlit internal changed: keep Streamlit's own (lazy) expiry
        log.debug("could not reap closed sessions", exc_info=True)
        return 0


def sweep(store: ResultStore) -> int:
    """One sweep: idle results and closed sessions out, and when anything went, the freed heap
    back to the operating system (gc for the sessions' reference cycles, then malloc_trim).
    """
    gone = store.expire() + reap_closed_sessions()
    if gone:
        gc.collect()
        memory.release_free_memory()
    return gone


def _sweep_forever(store: ResultStore, every_s: float) -> None:
    while True:
        time.sleep(every_s)
        try:
            sweep(store)
        except Exception:  # a sweep must never end the thread
            log.exception("result store sweep failed")


@st.cache_resource(show_spinner=False)
def result_store() -> ResultStore:
    """The process-wide result store (shared by every session and page), with a daemon thread
    that runs :func:`sweep` every quarter of the TTL, at most a minute apart (every minute
    without a TTL: closed sessions are reaped then too).
    """
    store = ResultStore(ttl_s=result_ttl_s())
    every = 60.0 if store.ttl_s is None else min(60.0, store.ttl_s / 4)
    threading.Thread(target=_sweep_forever, args=(store, every), daemon=True, name="navlab-sweep").start()
    return store


@st.cache_resource(show_spinner=False)
def ledger() -> memory.Ledger:
    """What all sessions' runs in flight may hold together: the memory budget at server start
    (NAVLAB_MEMORY_BUDGET, or half of the memory available then).
    """
    return memory.Ledger(memory.budget_bytes())


def cached_results(spec: ExperimentSpec) -> Results | None:
    return result_store().get(spec.to_json())


# --------------------------------------------------------------------------- chunked running


def first_chunk_size(total: int) -> int:
    """About a tenth of the runs (1 … 25): the first chart comes quickly."""
    return max(1, min(25, -(-total // 10)))


def next_chunk_size(remaining: int, big: int = 200) -> int:
    """After the first chunk: the rest at once, or thirds (≥ 100 runs) when more than ``big``.

    Every chunk pays the per-epoch Python overhead of every filter once (at ≈ 100 runs that
    overhead dominates), so after the quick first chunk the fewer chunks the faster; only long
    runs are split further so the page still updates while they work.
    """
    if remaining <= big:
        return remaining
    return max(100, -(-remaining // 3))


# What every filter cost per epoch in this process, per scenario: {runs in the batch: seconds}
# (the last few batch sizes). Only for choosing how to chunk a run, never shown as a measurement.
_COST: dict[tuple[str, str], dict[int, float]] = {}
_COST_LOCK = threading.Lock()  # sessions run in threads of one process
STREAM_ABOVE_S = 1.5  # a run expected to take less than this is computed in one batch
STREAM_GAIN = 0.5  # stream only if the first chunk takes at most this share of one batch
# Before a filter has run on a scenario: 1 ms per epoch up to 200 runs, growing with the runs
# beyond (numpy's per-call overhead dominates small batches: measured 0.1–2 ms per filter-epoch
# at 50–100 runs on cv2d and sins-gps).
_PRIOR = {200: 1e-3}


def learn_cost(scenario: str, runs: int, K: int, out: dict[str, FilterRun]) -> None:
    """Remember each filter's seconds per epoch at this batch size (the last 4 sizes)."""
    with _COST_LOCK:
        for key, fr in out.items():
            seen = dict(_COST.get((scenario, key), {}))
            seen.pop(runs, None)
            seen[runs] = fr.runtime_s / max(K, 1)
            while len(seen) > 4:
                seen.pop(next(iter(seen)))
            _COST[(scenario, key)] = seen  # replaced, never mutated: readers need no lock


def _per_epoch(seen: dict[int, float], runs: int) -> float:
    """Seconds per epoch at ``runs`` from costs at other batch sizes. Between the smallest and the
    largest size seen: the line through them (per-call overhead + per-run work); below: the
    smallest size's cost; beyond the largest: that cost scaled with the runs — an upper bound,
    since small batches are overhead-bound and the slope between two of them is mostly noise
    (a flat or falling pair once made a 30× larger run look short).
    """
    (b1, c1), (b2, c2) = min(seen.items()), max(seen.items())
    if runs >= b2:
        return c2 * runs / b2
    if runs <= b1:
        return c1
    return c1 + max(0.0, c2 - c1) * (runs - b1) / (b2 - b1)


Costs = dict[tuple[str, str], dict[int, float]]


def estimated_seconds(spec: ExperimentSpec, K: int, runs: int, costs: Costs | None = None) -> float | None:
    """Filter time of ``runs`` runs of ``spec`` from the costs learned so far (``costs``: a table
    to use instead, e.g. in tests; the prior for a filter not seen yet on this scenario); None if
    K is unknown.
    """
    if K <= 0:
        return None
    table = _COST if costs is None else costs
    return sum(K * _per_epoch(table.get((spec.scenario, key)) or _PRIOR, runs) for key in spec.filters)


def _one_batch(spec: ExperimentSpec, K: int, remaining: int, first: int, costs: Costs | None = None) -> bool:
    """Whether to run the remaining runs as one batch: known to be short, or streaming would
    not show results much sooner (the first chunk costs nearly a whole batch when per-epoch
    overhead dominates) and would only add that chunk's time.
    """
    total = estimated_seconds(spec, K, remaining, costs)
    if total is None:
        return False
    head = estimated_seconds(spec, K, first, costs)
    return total <= STREAM_ABOVE_S or (head is not None and head > STREAM_GAIN * total)


def stream_policy(spec: ExperimentSpec, K: int, first_chunk: int | None = None, costs: Costs | None = None):
    """The app's chunk policy for :func:`navlab.experiment.iter_experiment`: a quick first chunk
    (about a tenth of the runs), then the rest (thirds of long runs) — unless the costs learned in
    this process (or ``costs``) say the remainder takes less than ``STREAM_ABOVE_S`` or the first
    chunk would take more than ``STREAM_GAIN`` of one batch: then one batch, since every batch
    pays the per-epoch overhead of every filter again. ``first_chunk`` overrides the first size.
    """
    state = {"first": True}

    def policy(done: int, total: int) -> int:
        remaining = total - done
        if not state["first"]:
            return next_chunk_size(remaining)
        state["first"] = False
        n = min(remaining, first_chunk or first_chunk_size(total))
        if first_chunk is None and _one_batch(spec, K, remaining, n, costs):
            return remaining
        return n

    return policy


def iter_chunks(
    spec: ExperimentSpec | Plan,
    start: Results | None = None,
    first_chunk: int | None = None,
    on_epoch: Callable[[float], None] | None = None,
    costs: Costs | None = None,
) -> Iterator[Results]:
    """The app's streaming run: :func:`navlab.experiment.iter_experiment` with
    :func:`stream_policy`, resumable from partial results ``start``, learning each filter's cost
    after every chunk. ``on_epoch(runs_done)`` reports progress within a chunk.
    ``Results.elapsed_s`` is the compute time (simulation + filtering) summed over chunks.
    ``spec`` may be its :class:`~navlab.experiment.Plan` (planned once, passed on).
    """
    p = as_plan(spec)
    spec = p.spec
    policy = stream_policy(spec, p.scenario.epochs, first_chunk, costs)
    for res in iter_experiment(p, policy=policy, start=start, on_epoch=on_epoch):
        ch = res.last
        learn_cost(spec.scenario, ch.data.B, ch.data.K, ch.runs)
        yield res


def _partials() -> dict[str, tuple[str, Results]]:
    return st.session_state.setdefault(PARTIAL_KEY, {})


def partial_results(page: str, spec: ExperimentSpec) -> Results | None:
    """The session's interrupted (incomplete) results of ``spec`` on ``page``, if any."""
    hit = _partials().get(page)
    return hit[1] if hit and hit[0] == spec.to_json() else None


def request_run(page: str, spec: ExperimentSpec) -> None:
    st.session_state.setdefault(PENDING_KEY, {})[page] = spec.to_json()


def cancel_run(page: str) -> None:
    st.session_state.setdefault(PENDING_KEY, {}).pop(page, None)


def run_requested(page: str, spec: ExperimentSpec) -> bool:
    return st.session_state.get(PENDING_KEY, {}).get(page) == spec.to_json()


def show_error(exc: BaseException) -> None:
    """A user error as its message; anything else as a short error naming only the exception's
    type (its message can name server paths): the traceback goes to the server log.
    """
    if isinstance(exc, NavlabError):
        st.error(str(exc))
    else:
        log.error("a run failed", exc_info=exc)
        st.error(
            f"The run failed with an internal error ({type(exc).__name__}); the server log has the "
            "details. Try fewer runs or other settings, and report it if it persists."
        )


class _LiveProgress:
    """The progress bar and Stop button of :func:`run_live`, and a rerun asked for mid-chunk.

    A rerun (``RerunException``) raised by a Streamlit call made through :meth:`guarded` is held
    in ``pending`` until the chunk in flight is finished.
    """

    def __init__(
        self, spec: ExperimentSpec, page: str, start: Results | None, stop_button: bool, pc, sc
    ) -> None:
        self.runs = spec.runs
        self.prog = pc.progress(
            0.0 if start is None else start.done_runs / spec.runs, text="starting the Monte Carlo…"
        )
        self.stop_ph = sc.empty()
        if stop_button:
            self.stop_ph.button(
                "Stop",
                key=f"_stop_{page}",
                on_click=cancel_run,
                args=(page,),
                help="stop after the batch of runs in flight (it is kept); Run resumes where it stopped",
            )
        self.pending: list[BaseException] = []  # a rerun asked for mid-chunk, held until the chunk ends
        self.value = 0.0
        self.shown = 0.0

    def guarded(self, fn: Callable[..., Any], *args: Any, **kw: Any) -> None:
        """``fn(*args, **kw)``, holding a rerun it raises in ``pending``."""
        from streamlit.runtime.scriptrunner_utils.exceptions import RerunException

        try:
            fn(*args, **kw)
        except RerunException as exc:
            self.pending[:] = [exc]
            with contextlib.suppress(RerunException):
                self.prog.progress(self.value, text="finishing the batch in flight (kept), then stopping…")

    def tick(self, runs_done: float) -> None:
        """Progress within a batch, at most every 5 %."""
        if runs_done - self.shown >= 0.05 * self.runs and not self.pending:
            self.shown = runs_done
            self.value = min(1.0, runs_done / self.runs)
            self.guarded(self.prog.progress, self.value, text=f"{runs_done:.0f}/{self.runs} runs…")

    def chunk_done(self, res: Results) -> None:
        """Progress after a finished chunk."""
        self.value = res.done_runs / self.runs
        self.guarded(
            self.prog.progress,
            self.value,
            text=f"{res.done_runs}/{self.runs} runs · {res.elapsed_s:.2f} s compute",
        )

    def clear(self) -> None:
        self.prog.empty()
        self.stop_ph.empty()


def _compute_live(
    p: Plan,
    key: str,
    page: str,
    start: Results | None,
    first_chunk: int | None,
    partials: dict[str, tuple[str, Results]],
    live: _LiveProgress,
    render: Callable[[Results], None] | None,
) -> Results | None:
    """Run the remaining chunks within the memory budget, keeping each in ``partials`` and
    rendering it; stops after the chunk in flight once a rerun is pending. The last results.
    """
    res = None
    size = run_size(p)
    need = size.full()
    memory.check(size, need)  # this run alone (the message says what to change)
    with ledger().reserve(need):  # and all sessions' runs together
        for res in iter_chunks(p, start, first_chunk, live.tick):
            partials[page] = (key, res)  # no session_state access: that can raise a rerun
            if live.pending:
                break
            live.chunk_done(res)
            if render is not None and not live.pending:
                live.guarded(render, res)
            if live.pending:
                break
    return res


def _finish_stored(store: ResultStore, key: str, page: str, res: Results, render) -> Results:
    """Results found finished (in the store, or complete in the session): stored, shown, returned."""
    store.put(key, res)
    _partials().pop(page, None)
    cancel_run(page)
    if render is not None:
        render(res)
    return res


def run_live(
    spec: ExperimentSpec | Plan,
    page: str,
    render: Callable[[Results], None] | None = None,
    *,
    stop_button: bool = True,
    first_chunk: int | None = None,
    progress_container: Any = None,
    stop_container: Any = None,
) -> Results | None:
    """Finished results of ``spec``: from the store, or computed now with progress and streaming.

    ``render(res)`` is called with the accumulated results after every chunk (and once for a
    cached result); it should draw into ``st.empty()`` placeholders created before this call.
    The progress bar and the Stop button go into ``progress_container`` / ``stop_container``
    (default: where this is called), e.g. beside the Run button.

    A rerun the user asks for while a chunk computes (Stop, a view control) waits until that
    chunk is finished: the chunk in flight is kept with the others in the session, then the rerun
    happens, and Run (or the same page again) resumes from there. Returns None after a failure
    (already shown as an error). ``spec`` may be its :class:`~navlab.experiment.Plan` (the
    sidebar's, planned once and passed on).
    """
    planned = spec if isinstance(spec, Plan) else None
    spec = spec.spec if isinstance(spec, Plan) else spec
    key = spec.to_json()
    store = result_store()
    res = store.get(key)
    if res is not None:
        if render is not None:
            render(res)
        return res
    start = partial_results(page, spec)
    if start is not None and start.complete:  # a click during the last batch kept all of it
        return _finish_stored(store, key, page, start, render)
    # the session's dict, fetched once: reading st.session_state is one of Streamlit's yield
    # points, where a rerun asked for mid-chunk is raised; storing a finished chunk through it
    # could lose that chunk (measured: Stop at 630 of 3000 runs kept 25)
    partials = _partials()
    live = _LiveProgress(
        spec,
        page,
        start,
        stop_button,
        progress_container if progress_container is not None else st,
        stop_container if stop_container is not None else st,
    )
    if start is not None and render is not None:
        live.guarded(render, start)
    t0 = time.perf_counter()
    try:
        p = planned or plan(spec)
        res = _compute_live(p, key, page, start, first_chunk, partials, live, render)
    except Exception as exc:  # shown to the user, never a traceback
        live.clear()
        cancel_run(page)
        show_error(exc)
        return None
    if live.pending:  # the finished chunks (the one in flight included) are kept: now rerun
        if res is not None and res.complete:  # the last batch: finished, so stored now
            store.put(key, res)
            partials.pop(page, None)
        raise live.pending[0]
    assert res is not None
    live.stop_ph.empty()
    store.put(key, res)
    _partials().pop(page, None)
    cancel_run(page)
    live.prog.progress(
        1.0,
        text=f"done: {spec.runs} runs, {res.elapsed_s:.2f} s compute, "
        f"{time.perf_counter() - t0:.2f} s on the page",
    )
    return res


# --------------------------------------------------------------------------- metric cache
