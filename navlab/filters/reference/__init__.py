"""Plain reference implementations of the filters: one run, unbatched, the textbook formulas.

Every fast filter of :mod:`navlab.filters` is batched over Monte Carlo runs and takes shortcuts
where numpy's per-call overhead would dominate (closed-form inverses, products by indexing,
measurement-space iterations, …). The functions here are the same algorithms written the way the
papers and ALGORITHMS.md print them, for ONE run, with explicit inverses and loops, and a missing
channel handled by deleting its row (not by masking). They are slow on purpose and are not
registered as filters: ``tests/contract/test_reference.py`` runs every filter that has a
reference beside it on every compatible scenario and requires the same numbers.

:data:`REFERENCES` maps a filter key to its :class:`Reference`; a filter without one (``wls``,
which is plain already; ``nnmfukf``, whose network training is tested on its own; the filters
written as one-run steps — the VB, Sage–Husa and UKF families — whose steps are the textbook
form, checked compiled against uncompiled) is simply absent.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

from navlab.linalg import Array
from navlab.registry import Registry


class Trace(NamedTuple):
    """What a reference run produced, one entry per epoch k = 1 … K (None: not reported)."""

    x: Array  # (K, n)
    P: Array  # (K, n, n)
    R_hat: Array | None = None  # (K, m, m)
    weights: Array | None = None  # (K, m)
    flags: Array | None = None  # (K, m) codes of §0.3 (never 9: a reference does not repair)


@dataclass(frozen=True)
class Reference:
    """The plain transcription of filter ``key``.

    ``run(model, x0 (n,), P0 (n, n), z (K+1, m), sides, params) -> Trace`` with ``sides`` the
    per-epoch :class:`~navlab.filters.base.SideInfo` of this run (index k) and ``params`` the
    filter's parameter dataclass. ``missing``: it handles NaN channels (by deleting them).
    ``note``: what it does not implement (options it leaves out).
    """

    key: str
    run: Callable[..., Trace]
    missing: bool = True
    note: str = ""

    def __call__(self, *args: Any, **kwargs: Any) -> Trace:
        return self.run(*args, **kwargs)


#: Filter key → its plain reference (the modules of this package register theirs).
REFERENCES: Registry[Reference] = Registry("reference", package="navlab.filters.reference")


def reference(key: str, *, missing: bool = True, note: str = "") -> Callable[[Callable], Callable]:
    """Decorator registering ``fn`` as the reference of filter ``key``."""

    def deco(fn: Callable[..., Trace]) -> Callable[..., Trace]:
        REFERENCES.register(Reference(key, fn, missing, note))
        return fn

    return deco


__all__ = ["REFERENCES", "Reference", "Trace", "reference"]
