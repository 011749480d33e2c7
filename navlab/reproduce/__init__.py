"""Paper reproductions: each runs a paper's experiment and returns tidy rows
(experiment, filter, metric, value, paper, …) comparing navlab's number with the paper's.

A reproduction module defines a :class:`Reproduction` and registers it with :func:`register`;
every module of this package is imported so the CLI and the app see them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

# the columns every reproduction table has (more may follow)
COLUMNS = ["experiment", "filter", "metric", "value", "paper", "rel_diff", "unit", "note"]


@dataclass(frozen=True)
class Reproduction:
    """A paper's experiment. ``run(runs=None, seed=1, outdir=None) -> DataFrame`` (COLUMNS).

    ``runs=None`` uses the paper's Monte Carlo size; ``outdir`` (if given) receives per-epoch
    RMSE curves as CSV.
    """

    key: str
    title: str
    paper: str
    run: Callable[..., pd.DataFrame]


REPRODUCTIONS: dict[str, Reproduction] = {}


def register(rep: Reproduction) -> Reproduction:
    REPRODUCTIONS[rep.key] = rep
    return rep


def rel_diff(value: float, paper: float | None) -> float | None:
    """(navlab − paper)/paper, or None where the paper gives no number."""
    if paper is None or paper == 0:
        return None
    return (value - paper) / paper


def ensure_dir(outdir: Path | None) -> Path | None:
    if outdir is not None:
        outdir.mkdir(parents=True, exist_ok=True)
    return outdir


# every module of this package calls register(...) on import
def _discover() -> None:
    import importlib
    import pkgutil

    for m in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{m.name}")


_discover()
