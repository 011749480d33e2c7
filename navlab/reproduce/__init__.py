"""Paper reproductions: each declares a paper's experiments, the quantities measured on every
filter and the paper's claims (:mod:`navlab.reproduce.engine`), and is judged over many Monte Carlo
sets ("seeds") with a verdict per claim.

A reproduction module builds a :class:`~navlab.reproduce.engine.Reproduction` and passes it to
:func:`register`; every module of this package is imported on first use (navlab.registry), so the
CLI and the app see a new one without touching a list.
"""

from __future__ import annotations

from navlab.reproduce.engine import DEFAULT_SEEDS, REPRODUCTIONS, Outcome, Reproduction, register

__all__ = ["DEFAULT_SEEDS", "REPRODUCTIONS", "Outcome", "Reproduction", "register"]
