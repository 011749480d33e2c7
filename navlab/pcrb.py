"""The posterior Cramér–Rao bound (PCRB): the error floor no estimator can beat, under the
experiment's own noise — heavy tails and contamination included.

The oracle KF is a genie (told the true R(t) and which measurements are outliers): it can go
below what any real estimator reaches. The PCRB is the floor for an estimator that knows the
noise DENSITY (the schedule's σ(t), the outlier model and its rate) but not which draw was an
outlier. Recursion (Tichavský, Muravchik, Nehorai 1998) for dynamics x_k = F_k x_{k−1} + w_k,
w_k ~ N(0, Q_k), and measurements z_k = h_k(x_k) + v_k with independent entries v_kj of
Fisher information J_R,kj (:meth:`navlab.noise.OutlierModel.fisher`)::

    J_0 = P_0⁻¹,   J_k = (Q_k + F_k J_{k−1}⁻¹ F_kᵀ)⁻¹ + E[H_k(x_k)ᵀ diag(J_R,k ⊙ available_k) H_k(x_k)]

and E[e_k e_kᵀ] ⪰ J_k⁻¹ for every estimator. With Gaussian noise (J_R = 1/σ²) and a linear
model this is the Kalman filter's own covariance recursion (tested).

* **Exact** (scenarios with ``pcrb = "linear"``): H does not depend on the state, so the
  expectation is a number: the bound is computed from one simulated run's geometry.
* **Monte Carlo** (``pcrb = "monte-carlo"``: linear dynamics, nonlinear h, e.g. pseudoranges):
  the expectation is averaged over the simulated truth of the experiment's first
  :data:`MC_RUNS` runs; its interval is a bootstrap over those runs (:data:`MC_BOOT` resamples).
* Otherwise no bound (a scenario whose truth or noise is drawn from something no outlier model
  states, e.g. gps-ins-rtk's gross errors; an outlier model that states no density).

What the tables show (:func:`rows`): ``pcrb_<group>`` = √(mean over the analysis window of the
bound's trace over the group) — the floor of the pooled RMSE ``rmse_<group>`` — and per filter
``gap_<group>`` = rmse_<group> / pcrb_<group> with its interval (the RMSE's interval over the
bound; for a Monte Carlo bound, widened by the bound's own interval). A gap near 1: nothing
left to gain; the oracle, a genie, may go below 1.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from navlab import metrics as M
from navlab.experiment import ExperimentSpec, plan
from navlab.filters import is_oracle
from navlab.linalg import Array
from navlab.noise import OutlierModel
from navlab.scenarios.base import get_scenario_class

MC_RUNS = 200  # simulated truths a Monte Carlo bound averages over (at most the experiment's runs)
MC_BOOT = 200  # bootstrap resamples of those runs (the bound's interval)
KINDS = {"linear": "exact (linear model)", "monte-carlo": "Monte Carlo over the simulated truth"}


@dataclass(frozen=True, eq=False)
class Bound:
    """The bound on the error covariance at every epoch (K+1, n, n), and how it was made."""

    kind: str  # "linear" or "monte-carlo"
    P: Array  # (K+1, n, n)
    P_boot: Array | None  # (MC_BOOT, K+1, n) diagonals of the resampled bounds (Monte Carlo)
    runs: int  # simulated truths it averages over
    fisher: Array  # (K+1, m) J_R of every measurement entry

    def floor(self, idx: tuple[int, ...], window: Array, scale: float = 1.0) -> tuple[float, float, float]:
        """(floor, lo, hi) of the pooled RMSE over state components ``idx`` and epochs ``window``:
        √(mean_k Σ_i P_k,ii)·scale; lo = hi = floor when exact.
        """
        W = np.asarray(window, dtype=bool)
        d = np.einsum("kii->ki", self.P)[W][:, list(idx)]
        v = float(np.sqrt(d.sum(axis=1).mean())) * scale
        if self.P_boot is None:
            return v, v, v
        b = np.sqrt(self.P_boot[:, W][:, :, list(idx)].sum(axis=2).mean(axis=1)) * scale
        lo, hi = np.quantile(b, [0.025, 0.975])
        return v, float(lo), float(hi)


def why_none(spec: ExperimentSpec) -> str:
    """'' when the experiment has a bound, else why not (one sentence)."""
    kind = get_scenario_class(spec.scenario).pcrb  # before planning: a recording is not read
    if not kind:
        return (
            f"no PCRB for scenario '{spec.scenario}': its truth or noise is not drawn from a model "
            "the bound knows"
        )
    p = plan(spec.replace(runs=1))
    _, outliers = p.scenario.noise_models(p.schedule, p.outliers)
    if type(outliers).fisher is OutlierModel.fisher:  # the base: no density stated
        return f"no PCRB: outlier model '{outliers.key}' states no density"
    return ""


def information_recursion(F: Any, Q: Any, Jm: Array, P0: Array, Q_extra: Array | None = None) -> Array:
    """Bounds J_k⁻¹ (…, K+1, n, n) from J_0 = P0⁻¹ and the measurement information ``Jm``
    (…, K+1, n, n) (leading axes: independent recursions, e.g. bootstrap resamples). ``F(k)``,
    ``Q(k)``: the transition and process noise k−1 → k.
    """
    lead, K1, n = Jm.shape[:-3], Jm.shape[-3], Jm.shape[-1]
    out = np.empty((*lead, K1, n, n))
    P = np.broadcast_to(np.asarray(P0, dtype=float), (*lead, n, n)).copy()
    out[..., 0, :, :] = P
    for k in range(1, K1):
        Fk = np.asarray(F(k), dtype=float)
        Pp = Fk @ P @ Fk.T + np.asarray(Q(k), dtype=float)
        if Q_extra is not None:
            Pp = Pp + Q_extra[k]
        J = np.linalg.inv(0.5 * (Pp + np.swapaxes(Pp, -1, -2))) + Jm[..., k, :, :]
        P = np.linalg.inv(0.5 * (J + np.swapaxes(J, -1, -2)))
        P = 0.5 * (P + np.swapaxes(P, -1, -2))
        out[..., k, :, :] = P
    return out


@functools.lru_cache(maxsize=32)
def _bound(spec_json: str) -> Bound | None:
    spec = ExperimentSpec.from_json(spec_json)
    if why_none(spec):
        return None
    p = plan(spec.replace(runs=1))
    kind = type(p.scenario).pcrb
    runs = [0] if kind == "linear" else list(range(min(int(spec.runs), MC_RUNS)))
    d = p.scenario.simulate(p.schedule, p.outliers, runs, spec.seed)
    _, outliers = p.scenario.noise_models(p.schedule, p.outliers)
    JR = np.asarray(outliers.fisher(np.sqrt(np.asarray(d.R_schedule, dtype=float))), dtype=float)
    model = d.model
    K1, n = d.K + 1, int(d.x0.shape[1])
    avail = np.isfinite(d.z)  # (B, K+1, m)
    if kind == "linear":
        Jm = np.zeros((K1, n, n))
        for k in range(1, K1):
            H = np.asarray(model.H(None, k), dtype=float)
            Jm[k] = H.T @ ((JR[k] * avail[0, k])[:, None] * H)
        P = information_recursion(model.F, model.Q, Jm, d.P0, d.Q_extra)
        return Bound(kind, P, None, 1, JR)
    B = d.B
    per = np.zeros((B, K1, n, n))  # each run's measurement information
    for k in range(1, K1):
        H = np.asarray(model.H(np.ascontiguousarray(d.x_true[:, k]), k), dtype=float)
        H = np.broadcast_to(H, (B, *H.shape[-2:]))
        per[:, k] = np.einsum("bmi,bm,bmj->bij", H, JR[k] * avail[:, k], H)
    P = information_recursion(model.F, model.Q, per.mean(axis=0), d.P0, d.Q_extra)
    rng = np.random.default_rng(np.random.SeedSequence([int(spec.seed), 1998]))
    W = rng.multinomial(B, np.full(B, 1.0 / B), size=MC_BOOT) / B  # (MC_BOOT, B)
    Jb = np.einsum("sb,bkij->skij", W, per)
    Pb = information_recursion(model.F, model.Q, Jb, d.P0, d.Q_extra)
    return Bound(kind, P, np.einsum("skii->ski", Pb), B, JR)


def bound(spec: ExperimentSpec) -> Bound | None:
    """The PCRB of the experiment ``spec`` (None: no bound, :func:`why_none` says why). Cached."""
    kind = get_scenario_class(spec.scenario).pcrb
    if not kind:
        return None
    keep = spec.replace(filters=("kf",), filter_params={})
    if kind == "linear":
        keep = keep.replace(runs=1)  # an exact bound does not depend on the run count
    return _bound(keep.to_json())


def rows(res: Any, groups: list[str] | None = None) -> pd.DataFrame:
    """``pcrb_<group>`` (filter "pcrb") and per filter ``gap_<group>`` rows (:data:`navlab.metrics.COLUMNS`)
    for every error group of ``res`` (or those named) with a pooled RMSE; empty without a bound.
    """
    data = res.data
    if not getattr(data, "has_truth", False):
        return pd.DataFrame(columns=M.COLUMNS)
    b = bound(res.spec)
    if b is None:
        return pd.DataFrame(columns=M.COLUMNS)
    sm = M.summary(res)
    how = KINDS[b.kind] + (f", {b.runs} runs" if b.kind == "monte-carlo" else "")
    out = []
    for g, group in data.groups.items():
        if groups is not None and g not in groups:
            continue
        metric = f"rmse_{g}"
        v, lo, hi = b.floor(group.idx, data.window, group.scale)
        r = M.row("pcrb", "PCRB (floor)", f"pcrb_{g}", v, group.unit, note=how)
        if b.P_boot is not None:
            r.update(ci_lo=lo, ci_hi=hi, ci_method=f"bootstrap over the {b.runs} simulated truths")
        out.append(r)
        if not v > 0:
            continue
        for key, fr in res.runs.items():
            if metric not in sm.metrics_of(key):
                continue
            e = sm.estimate(key, metric)
            gr = M.row(key, fr.label, f"gap_{g}", e.value / v, "× floor", note=f"{metric} / pcrb_{g}")
            if e.has_ci:
                gr.update(ci_lo=e.lo / hi, ci_hi=e.hi / lo, ci_method=e.method)
            gr["runs_used"] = int(sm.judgement.judged[key].sum())
            out.append(gr)
    return pd.DataFrame(out, columns=M.COLUMNS)


def floor_text(res: Any, group: str, markdown: bool = True) -> str:
    """One sentence (Compare page; a table's footnote with ``markdown`` off): the floor of
    ``rmse_<group>``, the oracle's value and each filter's gap; '' when there is no bound.
    """
    df = rows(res, [group])
    f = df[df.metric == f"pcrb_{group}"]
    if f.empty:
        return ""
    fl = f.iloc[0]
    unit = fl["unit"]
    txt = (
        f"**Floor (posterior Cramér–Rao bound, {fl['note']})**: no estimator told only the noise "
        f"density (not which measurements are outliers) reaches a {group} RMSE below "
        f"**{fl['value']:.4g} {unit}**"
    )
    if np.isfinite(fl["ci_lo"]):
        txt += f" [{fl['ci_lo']:.4g}, {fl['ci_hi']:.4g}]"
    gaps = df[df.metric == f"gap_{group}"]
    orc = [r for r in gaps.itertuples() if is_oracle(r.filter)]
    if orc:
        txt += f"; the oracle (a genie, told them) is at {orc[0].value:.3g} × the floor"
    parts = [
        (f"{r.label} {r.value:.3g}×" if np.isfinite(r.value) else f"{r.label} — (no RMSE: no run judged)")
        + (f" [{r.ci_lo:.3g}, {r.ci_hi:.3g}]" if np.isfinite(r.ci_lo) else "")
        for r in gaps.itertuples()
        if not is_oracle(r.filter)
    ]
    if parts:
        txt += ". Gap (RMSE / floor): " + ", ".join(parts)
    txt += "."
    return txt if markdown else txt.replace("**", "")
