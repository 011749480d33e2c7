"""One-parameter sweeps: which parameters can be swept, their grids, and the sweep loop.

A sweepable parameter is any numeric, widget-visible parameter of the chosen scenario, noise
schedule, outlier model or filters, named like the widgets' keys (``ol.mixture.contamination``,
``fp.chi2-kf.alpha``, ``sc.cv2d.sigma_r2`` …). Every point is an ordinary ExperimentSpec, run
through the metric cache, so repeating or extending a sweep only computes new points.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec, plan
from navlab.filters import registry
from navlab.noise import OUTLIERS, SCHEDULES
from navlab.params import describe
from navlab.scenarios import scenario_registry

MAX_POINTS = 15


@dataclass(frozen=True)
class Sweepable:
    """A numeric parameter that a sweep can vary."""

    id: str  # "ol.mixture.contamination"
    kind: str  # sc | ns | ol | fp
    owner: str
    name: str
    label: str
    default: float
    lo: float | None
    hi: float | None
    integer: bool
    help: str = ""


def sweepables(spec: ExperimentSpec) -> list[Sweepable]:
    """Numeric parameters of the spec's outlier model, noise schedule, scenario and filters."""
    sreg, freg = scenario_registry(), registry()
    scls = sreg[spec.scenario]
    groups: list[tuple[str, str, type, dict[str, Any], str]] = [
        (
            "ol",
            spec.outliers,
            OUTLIERS[spec.outliers].Params,
            scls.outlier_defaults.get(spec.outliers, {}),
            f"outliers {spec.outliers}",
        ),
        (
            "ns",
            spec.noise_schedule,
            SCHEDULES[spec.noise_schedule].Params,
            {},
            f"noise {spec.noise_schedule}",
        ),
        ("sc", spec.scenario, scls.Params, {}, f"scenario {spec.scenario}"),
    ]
    groups += [
        ("fp", k, freg[k].Params, scls.filter_defaults.get(k, {}), f"filter {k}") for k in spec.filters
    ]
    out = []
    for kind, owner, Params, over, where in groups:
        for p in describe(Params):
            d = over.get(p["name"], p["default"])
            if not p.get("ui", True) or isinstance(d, bool) or not isinstance(d, (int, float)):
                continue
            out.append(
                Sweepable(
                    id=f"{kind}.{owner}.{p['name']}",
                    kind=kind,
                    owner=owner,
                    name=p["name"],
                    label=f"{p['name'].replace('_', ' ')} ({where})",
                    default=float(d),
                    lo=p.get("lo"),
                    hi=p.get("hi"),
                    integer=isinstance(d, int),
                    help=p.get("help", ""),
                )
            )
    return out


def default_range(s: Sweepable) -> tuple[float, float]:
    """A sensible default range: the admissible range clipped around the default."""
    d = s.default
    if s.id.endswith(".contamination"):
        lo, hi = 0.0, 0.3
    elif d > 0:
        lo, hi = d / 4, d * 4
    else:
        lo, hi = (s.lo if s.lo is not None else -1.0), (s.hi if s.hi is not None else 1.0)
    if s.lo is not None:
        lo = max(lo, s.lo)
    if s.hi is not None:
        hi = min(hi, s.hi)
    if s.integer:
        lo, hi = math.ceil(lo), math.floor(hi)
    return float(lo), float(hi)


def grid(s: Sweepable, lo: float, hi: float, n: int, log: bool) -> np.ndarray:
    """``n`` values from lo to hi (log-spaced if ``log``), inside the admissible range."""
    if not 2 <= n <= MAX_POINTS:
        raise NavlabError(f"choose between 2 and {MAX_POINTS} sweep points")
    if not hi > lo:
        raise NavlabError("the sweep's upper end must be larger than its lower end")
    if (s.lo is not None and lo < s.lo) or (s.hi is not None and hi > s.hi):
        raise NavlabError(f"'{s.name}' must stay within [{s.lo}, {s.hi}]")
    if log:
        if lo <= 0:
            raise NavlabError("a log-spaced sweep needs a positive lower end")
        v = np.geomspace(lo, hi, n)
    else:
        v = np.linspace(lo, hi, n)
    if s.integer:
        v = np.unique(np.round(v).astype(int)).astype(float)
    return v


def apply(spec: ExperimentSpec, s: Sweepable, value: float) -> ExperimentSpec:
    """The spec with parameter ``s`` set to ``value`` (validated by :func:`plan`)."""
    v: Any = round(value) if s.integer else float(value)
    if s.kind == "sc":
        new = spec.replace(scenario_params={**spec.scenario_params, s.name: v})
        if s.name == "epochs":
            new = new.replace(epochs=None)
    elif s.kind == "ns":
        new = spec.replace(noise_params={**spec.noise_params, s.name: v})
    elif s.kind == "ol":
        extra = {}
        if s.name == "contamination":
            extra["contamination"] = None
        if s.name == "scale":
            extra["outlier_scale"] = None
        new = spec.replace(outlier_params={**spec.outlier_params, s.name: v}, **extra)
    elif s.kind == "fp":
        fp = {k: dict(d) for k, d in spec.filter_params.items()}
        fp.setdefault(s.owner, {})[s.name] = v
        new = spec.replace(filter_params=fp)
    else:
        raise NavlabError(f"unknown sweep parameter kind {s.kind!r}")
    plan(new)
    return new


def run_sweep(
    spec: ExperimentSpec,
    s: Sweepable,
    values: np.ndarray,
    metrics: Callable[[ExperimentSpec], pd.DataFrame],
    on_point: Callable[[int, int, pd.DataFrame], None] | None = None,
) -> pd.DataFrame:
    """Tidy table (value, filter, label, metric, metric_value, unit) over the grid.

    ``metrics(spec)`` returns :func:`navlab.metrics.summarize`'s table (the page passes the cached
    runner); ``on_point(i, n, table_so_far)`` is called after each point.
    """
    frames: list[pd.DataFrame] = []
    for i, v in enumerate(values):
        m = metrics(apply(spec, s, float(v))).copy()
        m = m.rename(columns={"value": "metric_value"})
        m.insert(0, "value", float(v))
        frames.append(m)
        if on_point is not None:
            on_point(i + 1, len(values), pd.concat(frames, ignore_index=True))
    return pd.concat(frames, ignore_index=True)
