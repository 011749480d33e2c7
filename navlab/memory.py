"""Memory budget: what a run will hold, estimated from its size before anything is computed.

A full run keeps per-epoch arrays of every filter (state, covariance diagonal, innovation,
weights, flags, NEES/NIS …, ≈ 250–300 bytes per run-epoch per filter on cv2d) and the simulated
data; a *summary* run (``run_experiment(..., summary=True)``, ``navlab run --summary``) keeps only
per-run statistics (the metrics' sufficient statistics) and works through the runs in chunks, so a
million-run Monte Carlo fits in a few hundred MB.

The budget is ``NAVLAB_MEMORY_BUDGET`` (e.g. ``8GB``, ``500MB``, or bytes) or, by default, half
of the memory the machine has available when the run starts (``MemAvailable`` of /proc/meminfo).
A run whose estimate exceeds it is refused with a message giving the estimate, the budget and what
to change (:func:`check`). The app also bounds what all sessions hold at once
(:class:`Ledger`).
"""

from __future__ import annotations

import math
import os
import re
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from navlab.errors import NavlabError

ENV = "NAVLAB_MEMORY_BUDGET"
SHARE = 0.5  # default budget: this share of the available memory
FALLBACK = 4 * 2**30  # if the available memory cannot be read
# floats (8 bytes) kept per run-epoch by one filter in a full run: x and P_diag (n each),
# innov, S_diag, R_used, R_hat, weights (m each), flags (m bytes), NIS, NEES, and a margin of
# 2 m for per-step statistics; transient work arrays of the time loop: a few (n × n) per run
_UNITS = {"": 1, "b": 1, "k": 2**10, "kb": 2**10, "m": 2**20, "mb": 2**20, "g": 2**30, "gb": 2**30}


def parse_bytes(text: str, what: str = "a memory budget", hint: str = "") -> int:
    """'8GB', '500 MB', '1.5g', '123456' → bytes; NavlabError naming ``what`` (and ``hint``:
    what else to do) on anything else.
    """
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([kmg]?b?)\s*", str(text).lower())
    if not m:
        raise NavlabError(f"{what} must be a memory size such as 8GB, 500MB or 1048576, got {text!r}{hint}")
    value = float(m.group(1)) * _UNITS[m.group(2)]
    if not value >= 1:
        raise NavlabError(f"{what} must be positive, got {text!r}{hint}")
    return int(value)


def available_bytes() -> int:
    """Memory the machine has available now (MemAvailable), or a fallback where unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return FALLBACK


def budget_bytes(budget: int | str | None = None) -> int:
    """The budget of one run: ``budget`` if given, else NAVLAB_MEMORY_BUDGET, else half of the
    available memory.
    """
    if budget is None:
        budget = os.environ.get(ENV) or None
    if budget is None:
        return int(SHARE * available_bytes())
    if isinstance(budget, str):
        return parse_bytes(budget)
    if isinstance(budget, bool) or not isinstance(budget, (int, float)) or not math.isfinite(budget):
        raise NavlabError(f"a memory budget must be a number of bytes or a size such as 8GB, got {budget!r}")
    return int(budget)


def fmt_bytes(n: float) -> str:
    for unit, size in (("GB", 2**30), ("MB", 2**20), ("kB", 2**10)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} bytes"


@dataclass(frozen=True)
class Size:
    """The dimensions that decide a run's memory."""

    runs: int
    epochs: int  # K (the arrays have K + 1 epochs)
    n: int  # states
    m: int  # measurement channels
    filters: int

    def per_run_epoch(self) -> float:
        """Bytes one run-epoch holds in a full run (all filters and the data)."""
        per_filter = 8 * (2 * self.n + 6 * self.m + 2 + 2 * self.m) + self.m
        data = 8 * (self.n + 3 * self.m) + self.m
        return self.filters * per_filter + data

    def full(self) -> float:
        """Bytes of a full run: every per-epoch array, plus the loop's work arrays."""
        work = self.filters * self.runs * 8 * 8 * (self.n * self.n + self.m * self.m)
        return self.runs * (self.epochs + 1) * self.per_run_epoch() + work

    def summary(self, chunk: int, keep_epochs: bool) -> float:
        """Bytes of a summary run with chunks of ``chunk`` runs: one chunk's full arrays plus the
        per-run statistics of every run (≈ 30 float32 numbers per filter, and up to 8 groups'
        per-epoch squared errors when ``keep_epochs``).
        """
        one = Size(min(chunk, self.runs), self.epochs, self.n, self.m, self.filters).full()
        per_run = self.filters * 4 * (30 + (8 * (self.epochs + 1) if keep_epochs else 0))
        return one + self.runs * per_run


def budget_source(budget: int | str | None = None) -> str:
    """Where the budget of :func:`budget_bytes` comes from, in words."""
    if budget is not None:
        return "the budget asked for"
    if os.environ.get(ENV):
        return f"{ENV}={os.environ[ENV]}"
    return f"{int(SHARE * 100)} % of the available memory"


def check(
    size: Size,
    what: float,
    budget: int | str | None = None,
    summary: bool = False,
    as_summary: float | None = None,
) -> None:
    """Refuse a run whose estimate ``what`` (bytes) exceeds the budget, saying what to change
    (``as_summary``: the estimate of the same run as a summary run, offered as an alternative).
    """
    limit = budget_bytes(budget)
    if what <= limit:
        return
    shape = f"{size.runs} runs × {size.epochs + 1} epochs × {size.filters} filter(s)"
    msg = (
        f"this run would hold about {fmt_bytes(what)} ({shape}), more than the memory budget of "
        f"{fmt_bytes(limit)} ({budget_source(budget)}); "
    )
    if summary:
        msg += "use fewer runs or epochs, or raise the budget (--memory-budget / NAVLAB_MEMORY_BUDGET)"
    else:
        msg += "use fewer runs or epochs, raise the budget (--memory-budget / NAVLAB_MEMORY_BUDGET)"
        if as_summary is not None and as_summary <= limit:
            msg += (
                ", or run it as a summary (--summary: metrics without the per-epoch arrays, about "
                f"{fmt_bytes(as_summary)})"
            )
    raise NavlabError(msg)


def release_free_memory() -> None:
    """Give freed heap memory back to the operating system (glibc's malloc_trim; a no-op
    elsewhere). After a large run the process otherwise keeps its peak size.
    """
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


class Ledger:
    """Bytes reserved by the runs in flight across every session of one server process.

    :meth:`reserve` waits (up to ``wait_s``) while the reservations would exceed ``limit``, then
    refuses with a message; a reservation is released when its block ends, even on an error.
    """

    def __init__(self, limit: int) -> None:
        self.limit = int(limit)
        self.held: dict[int, int] = {}
        self._cond = threading.Condition()
        self._next = 0

    @property
    def in_use(self) -> int:
        return sum(self.held.values())

    @contextmanager
    def reserve(self, nbytes: float, wait_s: float = 30.0) -> Iterator[None]:
        need = int(nbytes)
        if need > self.limit:
            raise NavlabError(
                f"this run needs about {fmt_bytes(need)}, more than this server allows all runs "
                f"together ({fmt_bytes(self.limit)}): use fewer runs or epochs"
            )
        deadline = time.monotonic() + wait_s
        with self._cond:
            while self.in_use + need > self.limit:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise NavlabError(
                        f"the server is busy: other runs hold {fmt_bytes(self.in_use)} of the "
                        f"{fmt_bytes(self.limit)} all runs may use together, and this one needs "
                        f"{fmt_bytes(need)}; press Run again in a moment, or use fewer runs"
                    )
                self._cond.wait(left)
            self._next += 1
            token = self._next
            self.held[token] = need
        try:
            yield
        finally:
            with self._cond:
                self.held.pop(token, None)
                self._cond.notify_all()
            release_free_memory()
