"""Paper reproductions: each declares a paper's experiments, the quantities measured on every
filter and the paper's claims (:mod:`navlab.reproduce.engine`), and is judged over many Monte Carlo
sets ("seeds") with a verdict per claim.

A reproduction module builds a :class:`~navlab.reproduce.engine.Reproduction` and passes it to
:func:`register`; every module of this package is imported so the CLI and the app see them.
"""

from __future__ import annotations

from navlab.reproduce.engine import DEFAULT_SEEDS, Outcome, Reproduction

__all__ = ["DEFAULT_SEEDS", "REPRODUCTIONS", "Outcome", "Reproduction", "register"]

REPRODUCTIONS: dict[str, Reproduction] = {}


def register(rep: Reproduction) -> Reproduction:
    """Add a reproduction to the registry under ``rep.key``."""
    if rep.key in REPRODUCTIONS and REPRODUCTIONS[rep.key] is not rep:
        raise ValueError(f"reproduction key {rep.key!r} registered twice")
    REPRODUCTIONS[rep.key] = rep
    return rep


# every module of this package (but the engine) calls register(...) on import
def _discover() -> None:
    import importlib
    import pkgutil

    for m in pkgutil.iter_modules(__path__):
        if m.name != "engine":
            importlib.import_module(f"{__name__}.{m.name}")


_discover()
