"""The engine of the Sweep and Tune pages: the server's results store and task executor, and
running a job of tasks with a progress bar and a Stop button.

The sweep and tuning logic itself is the library's (:mod:`navlab.sweep`, :mod:`navlab.tune`),
shared with the CLI. Tasks run on the cluster named by ``NAVLAB_DASK_SCHEDULER``
(``tcp://HOST:8786``), by default on this machine (:class:`navlab.cluster.LocalExecutor`): in the
server process while the work is short, on an embedded cluster — started in the background when
a job's work is long, then kept warm and shared between sessions — when it pays (``serial``:
always in the server process). The progress bar says where the tasks run, and at the end
where they ran and why.

Every finished task is in the results store (``NAVLAB_STORE``), so Stop keeps everything
finished, Run resumes, and a page opened again (even after a server restart) shows the finished
points at once.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import streamlit as st

from navlab import cluster
from navlab.store import Store
from navlab.sweep import (  # noqa: F401  (the pages import them from here)
    MAX_POINTS,
    Axis,
    Sweepable,
    apply,
    default_range,
    grid,
    make_sweep,
    paper_tables,
    run_sweep,
    sweepables,
)
from navlab.ui.runner import show_error

PENDING_KEY = "_navlab_jobs"  # session: {page: job id} — a job the user asked for


@st.cache_resource(show_spinner=False)
def app_store() -> Store:
    """The server's results store (NAVLAB_STORE, default ~/.cache/navlab/store)."""
    return Store.open()


def app_executor() -> Any:
    """The executor of NAVLAB_DASK_SCHEDULER (default: this machine, :mod:`navlab.cluster`)."""
    return cluster.executor(os.environ.get(cluster.ENV) or "local")


def where_text() -> str:
    """Where this server's tasks run, in words."""
    addr = (os.environ.get(cluster.ENV) or "local").strip()
    if addr == "serial":
        return "in the server process"
    if addr == "local":
        return (
            "in the server process, or on an embedded Dask cluster "
            f"({cluster.cpu_count()} workers) when the work is long enough to pay for it"
        )
    return f"on the Dask cluster at {addr}"


def request(page: str, job: str) -> None:
    st.session_state.setdefault(PENDING_KEY, {})[page] = job


def cancel(page: str) -> None:
    st.session_state.setdefault(PENDING_KEY, {}).pop(page, None)


def requested(page: str, job: str) -> bool:
    return st.session_state.get(PENDING_KEY, {}).get(page) == job


def stored_only() -> bool:
    """A ``should_stop`` that computes nothing: what the store already holds."""
    return True


def run_job(
    page: str,
    stop_container: Any,
    work: Callable[..., Any],
    *,
    what: str = "tasks",
    where: str | None = None,
) -> Any:
    """Run ``work(store=…, executor=…, on_progress=…, tick=…)`` with a progress bar and a Stop
    button (in ``stop_container``). Returns its result, or None after an error (shown).
    ``where``: where the work runs, in words, when it brings its own processes (a reproduction):
    ``work`` then gets no executor. Otherwise the bar says where the tasks run (the app's
    executor), and at the end where they ran and why.

    Stop reruns the page: the job is interrupted at its next progress update (at most
    :data:`navlab.cluster.POLL_S` while waiting on a cluster), the finished tasks are kept in
    the store and the tasks still running are cancelled.
    """
    ex = None if where is not None else app_executor()

    def place() -> str:
        return where if ex is None else ex.now

    bar = st.progress(0.0, text=f"starting ({place()})…")
    stop_slot = stop_container.empty()  # emptied when the job ends: nothing left to stop
    stop_slot.button(
        "Stop",
        key=f"_stop_{page}",
        on_click=cancel,
        args=(page,),
        help="stop now: every finished task is kept, Run resumes where it stopped",
    )
    state = {"done": 0, "total": 1}

    def progress(done: int, total: int) -> None:
        state.update(done=done, total=max(total, 1))
        tick()

    def tick() -> None:  # an element update: Streamlit handles a pending Stop here
        done, total = state["done"], state["total"]
        bar.progress(min(1.0, done / total), text=f"{done}/{total} {what} · {place()}")

    try:
        if ex is None:
            return work(store=app_store(), on_progress=progress, tick=tick)
        out = work(store=app_store(), executor=ex, on_progress=progress, tick=tick)
        bar.progress(1.0, text=f"Done: {ex.report}.")
        return out
    except Exception as exc:  # shown as a message, never a traceback (the server log has it)
        bar.empty()
        show_error(exc)
        return None
    finally:
        stop_slot.empty()
        cancel(page)
