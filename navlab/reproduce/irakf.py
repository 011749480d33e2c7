"""Reproduction of Ge, Zhang, Tang 2020 (IRAKF), §3: 2-D tracking with isolated / continuous outliers.

The paper (§3, Figs. 2–3) runs 100 Monte Carlo runs of the ``cv2d`` scenario (ALGORITHMS.md §8.2)
with outliers on the x-position measurement — experiment 1 ``isolated``: every 5 epochs in 20–70,
N(10, 64); experiment 2 ``continuous``: epochs 50–70, N(0, 64) — and compares SKF, RRAE, RAKF,
RSSHAKF and IRAKF. Its numbers (text of §3):

* isolated: position RMSE IRAKF 1.5942 m, RRAE 2.1969 m (IRAKF 27.43 % better), RSSHAKF 2.1818 m;
* continuous: IRAKF 1.4663 m and 0.3367 m/s, RRAE 1.9583 m and 0.5475 m/s; SKF, RAKF and RSSHAKF
  have a maximum position error above 10 m during epochs 50–70.

The paper's "位置RMSE" is not defined beyond the per-epoch eq. 9 and its figures show the x axis,
so several readings are computed (all over the runs that did not diverge):

=========================  ============================================================
``rmse_x_pos`` (default)   sqrt(mean over k = 1 … K and runs of e_x²) — §8.2, §10 #18
``mean_rmse_x_pos``        mean over k = 1 … K of the per-epoch RMSE_k (eq. 9) of x
``rmse_pos_2d``            pooled over k and runs of the 2-D error norm e_x² + e_y²
``rmse_pos_per_axis``      the same divided by the two axes: sqrt(mean (e_x² + e_y²)/2)
``rmse_x_pos_window``      pooled, x only, over the outlier window (20–70 or 50–70)
``mean_rmse_x_pos_window`` mean of RMSE_k over the outlier window
=========================  ============================================================

and the same for the velocity (``…_vel``). Each paper number sits on every reading of its
quantity; the note marks the default and the reading closest to the paper. The comparators RRAE,
RAKF and RSSHAKF are RECONSTRUCTIONS (§4.7–4.9) and the paper does not give the RAE window, the
detector threshold C, P0 or the run length: those are navlab's documented defaults (§10).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from navlab.experiment import ExperimentSpec, Results, run_experiment
from navlab.reproduce import COLUMNS, Reproduction, ensure_dir, register, rel_diff

PAPER = (
    "Ge, Zhang, Tang 2020, Navigation Positioning and Timing 7(1) (IRAKF), §3, "
    "doi:10.19306/j.cnki.2095-8110.2020.01.007"
)
DEFAULT_RUNS = 100  # the paper's Monte Carlo size
FILTERS = ("kf", "rrae", "rakf", "rsshakf", "irakf", "oracle-kf")
NAMES = {
    "kf": "SKF",
    "rrae": "RRAE",
    "rakf": "RAKF",
    "rsshakf": "RSSHAKF",
    "irakf": "IRAKF",
    "oracle-kf": "oracle KF",
}
EXPERIMENTS = {"isolated": (20, 70), "continuous": (50, 70)}  # outlier window (inclusive)
PAPER_VALUES = {
    ("isolated", "irakf", "pos"): 1.5942,
    ("isolated", "rrae", "pos"): 2.1969,
    ("isolated", "rsshakf", "pos"): 2.1818,
    ("continuous", "irakf", "pos"): 1.4663,
    ("continuous", "irakf", "vel"): 0.3367,
    ("continuous", "rrae", "pos"): 1.9583,
    ("continuous", "rrae", "vel"): 0.5475,
}
PAPER_IMPROVEMENT_PCT = 27.43  # isolated: (RRAE − IRAKF)/RRAE
PAPER_MAX_ABOVE = 10.0  # continuous: SKF, RAKF, RSSHAKF "maximum position error > 10 m"
DEFAULT = {"pos": "rmse_x_pos", "vel": "rmse_x_vel"}
UNITS = {"pos": "m", "vel": "m/s"}
COMP = {"pos": (0, 2), "vel": (1, 3)}  # x, y indices of the state

WHY = {
    "rrae": "RRAE is a RECONSTRUCTION (§4.7: IGG-III middle zone as equivalent variance, k1 = 5); "
    "the 2018 paper was not retrievable",
    "rsshakf": "RSSHAKF is a RECONSTRUCTION (§4.9); its RMSE is heavy-tailed over seeds (a few runs "
    "run away early when the Sage–Husa R̂ and the variance inflation feed each other)",
    "rakf": "RAKF is a RECONSTRUCTION from the abstract (§4.8)",
    "irakf": "the paper leaves the RAE window, C, P0 and the run length open (navlab: M = 10, "
    "C = 3, P0 = diag(4, 1, 4, 1), K = 100, §10)",
}
WHY_CONT_POS = (
    "; ALGORITHMS.md §4.6: no reasonable variant (window 5/20, k0/k1, P_ref policy, excluding "
    "rejected residuals) gets IRAKF below ≈ 1.9 m in experiment 2 — treated as not reproducible"
)


def _errors(res: Results, key: str) -> tuple[np.ndarray, np.ndarray]:
    """Errors (B_ok, K+1, n) of the runs that did not diverge, and that mask (B,)."""
    fr = res.runs[key]
    ok = ~fr.diverged
    return (fr.x - res.data.x_true)[ok], ok


def readings(e: np.ndarray, quantity: str, window: np.ndarray) -> dict[str, float]:
    """The plausible readings of the paper's single RMSE number (module docstring)."""
    ix, iy = COMP[quantity]
    q = quantity
    ex2, ey2 = e[:, :, ix] ** 2, e[:, :, iy] ** 2
    allk = np.zeros(e.shape[1], dtype=bool)
    allk[1:] = True  # k = 1 … K (the initial epoch excluded)
    rmse_k = np.sqrt(ex2.mean(axis=0))
    return {
        f"rmse_x_{q}": float(np.sqrt(ex2[:, allk].mean())),
        f"mean_rmse_x_{q}": float(rmse_k[allk].mean()),
        f"rmse_{q}_2d": float(np.sqrt((ex2 + ey2)[:, allk].mean())),
        f"rmse_{q}_per_axis": float(np.sqrt(0.5 * (ex2 + ey2)[:, allk].mean())),
        f"rmse_x_{q}_window": float(np.sqrt(ex2[:, window].mean())),
        f"mean_rmse_x_{q}_window": float(rmse_k[window].mean()),
    }


def _experiment(res: Results, experiment: str) -> list[dict]:
    d = res.data
    lo, hi = EXPERIMENTS[experiment]
    window = (np.arange(d.K + 1) >= lo) & (np.arange(d.K + 1) <= hi)
    rows: list[dict] = []
    values: dict[tuple[str, str], float] = {}
    runs_note = "" if d.B >= DEFAULT_RUNS else f"; {d.B} Monte Carlo runs (paper 100)"

    def add(key: str, metric: str, value: float, unit: str, paper=None, note: str = "") -> None:
        values[(key, metric)] = value
        rows.append(
            dict(
                experiment=experiment,
                filter=key,
                metric=metric,
                value=float(value),
                paper=paper,
                rel_diff=rel_diff(float(value), paper),
                unit=unit,
                note=note,
            )
        )

    for key in res.runs:
        e, ok = _errors(res, key)
        fr = res.runs[key]
        for q in ("pos", "vel"):
            paper = PAPER_VALUES.get((experiment, key, q))
            r = readings(e, q, window)
            closest = None
            if paper is not None:
                closest = min(r, key=lambda name: abs(r[name] - paper))
            for metric, value in r.items():
                notes = []
                if metric == DEFAULT[q]:
                    notes.append("default reading (pooled over k = 1…K and runs, x only; §8.2)")
                if metric == closest:
                    notes.append("reading closest to the paper")
                if paper is not None and metric == DEFAULT[q]:
                    rd = rel_diff(value, paper)
                    if rd is not None and abs(rd) > 0.2:
                        why = WHY.get(key, "")
                        if experiment == "continuous" and key == "irakf" and q == "pos":
                            why += WHY_CONT_POS
                        notes.append(f"differs by {100 * rd:+.0f} %: {why}{runs_note}")
                add(key, metric, value, UNITS[q], paper if paper is not None else None, "; ".join(notes))
        # maximum x-position error in the outlier window: the per-epoch RMSE curve's peak
        # (what Fig. 3 plots if it shows RMSE) and the mean over runs of each run's peak |e_x|
        # (what it shows if it is one run); the paper: > 10 m for SKF, RAKF, RSSHAKF
        ex = np.abs(e[:, :, 0])
        max_rmse = float(np.sqrt((ex**2).mean(axis=0))[window].max())
        run_max = float(ex[:, window].max(axis=1).mean())
        paper_says = experiment == "continuous" and key in ("kf", "rakf", "rsshakf")
        note = f"paper: > {PAPER_MAX_ABOVE:g} m (Fig. 3)" if paper_says else ""
        add(key, "max_rmse_x_pos_window", max_rmse, "m", None, note)
        add(key, "mean_run_max_abs_x_pos_window", run_max, "m", None, note)
        r_y = float(np.sqrt((e[:, 1:, 2] ** 2).mean()))
        add(
            key,
            "rmse_y_pos",
            r_y,
            "m",
            None,
            "clean channel; paper Fig. 2(c): all but RRAE comparable" if key == "irakf" else "",
        )
        if key != "oracle-kf":
            W1 = np.arange(d.K + 1) >= 1
            mask = d.outlier_mask[ok][:, W1]
            rejected = np.isin(fr.flags[ok][:, W1], (2, 3))
            anyflag = fr.flags[ok][:, W1] != 0
            add(
                key,
                "rejected_outliers_pct",
                100 * rejected[mask].mean(),
                "%",
                None,
                "channels rejected (flags 2/3) among injected outliers",
            )
            add(
                key,
                "flagged_outliers_pct",
                100 * anyflag[mask].mean(),
                "%",
                None,
                "any flag (incl. down-weighted) among injected outliers",
            )
            add(
                key,
                "rejected_clean_pct",
                100 * rejected[~mask].mean(),
                "%",
                None,
                "false rejections among clean channel-epochs",
            )
        add(key, "diverged", int(fr.diverged.sum()), "runs")
    # the paper's relative improvement of IRAKF over RRAE (experiment 1)
    if experiment == "isolated" and ("irakf", "rmse_x_pos") in values:
        imp = (
            100
            * (values[("rrae", "rmse_x_pos")] - values[("irakf", "rmse_x_pos")])
            / values[("rrae", "rmse_x_pos")]
        )
        note = "(RRAE − IRAKF)/RRAE on the default reading"
        if abs(imp - PAPER_IMPROVEMENT_PCT) > 10:
            note += (
                "; ALGORITHMS.md §4.7: the reconstructed RRAE lands inside the IRAKF band, "
                "so the paper's 27 % margin is not expected to reproduce"
            )
        add("irakf", "improvement_over_rrae_pct", imp, "%", PAPER_IMPROVEMENT_PCT, note)
    _ordering_notes(rows, values, experiment)
    _floor_notes(rows, values)
    return rows


def _floor_notes(rows: list[dict], values: dict) -> None:
    """Flag paper numbers below the oracle KF (true R, known outlier mean: the MMSE floor)."""
    for r in rows:
        if r["paper"] is None or r["filter"] == "oracle-kf":
            continue
        floor = values.get(("oracle-kf", r["metric"]))
        if floor is not None and r["paper"] < floor:
            msg = (
                f"the paper's {r['paper']:g} lies below the oracle KF's {floor:.3f} on this "
                "reading (the MMSE floor of navlab's setup), so no filter can reach it here"
            )
            r["note"] = f"{r['note']}; {msg}" if r["note"] else msg


def _ordering_notes(rows: list[dict], values: dict, experiment: str) -> None:
    """Say, with the numbers, where the paper's ordering does not hold (on IRAKF's rows)."""
    msgs = []
    ir = values.get(("irakf", "rmse_x_pos"))
    if ir is not None:
        better = [
            (k, v)
            for (k, m), v in values.items()
            if m == "rmse_x_pos" and k not in ("irakf", "oracle-kf") and v <= ir
        ]
        if better:
            txt = ", ".join(f"{NAMES[k]} {v:.3f} m" for k, v in better)
            msgs.append(("rmse_x_pos", f"paper: IRAKF best; here IRAKF {ir:.3f} m vs {txt}"))
    irv = values.get(("irakf", "rmse_x_vel"))
    if experiment == "continuous" and irv is not None:
        better = [
            (k, v)
            for (k, m), v in values.items()
            if m == "rmse_x_vel" and k not in ("irakf", "oracle-kf") and v <= irv
        ]
        if better:
            txt = ", ".join(f"{NAMES[k]} {v:.3f} m/s" for k, v in better)
            msgs.append(("rmse_x_vel", f"paper: IRAKF best; here IRAKF {irv:.3f} m/s vs {txt}"))
    if experiment == "continuous":
        for metric in ("max_rmse_x_pos_window", "mean_run_max_abs_x_pos_window"):
            irm = values.get(("irakf", metric))
            if irm is None:
                continue
            worse = [
                (k, values[(k, metric)])
                for k in ("kf", "rakf", "rsshakf")
                if (k, metric) in values and values[(k, metric)] <= irm
            ]
            above = [
                k for k in ("kf", "rakf", "rsshakf") if values.get((k, metric), np.inf) <= PAPER_MAX_ABOVE
            ]
            parts = []
            if worse:
                parts.append(
                    "paper: IRAKF's peak error below SKF, RAKF, RSSHAKF; here IRAKF "
                    f"{irm:.2f} m vs " + ", ".join(f"{NAMES[k]} {v:.2f} m" for k, v in worse)
                )
            if above:
                parts.append("paper: > 10 m for " + ", ".join(NAMES[k] for k in above) + "; here ≤ 10 m")
            if parts:
                msgs.append((metric, "; ".join(parts)))
    for metric, msg in msgs:
        for r in rows:
            if r["filter"] == "irakf" and r["metric"] == metric:
                r["note"] = f"{r['note']}; {msg}" if r["note"] else msg


CURVES = {"x_pos": (0, "m"), "x_vel": (1, "m/s"), "y_pos": (2, "m")}


def curves(res: Results) -> dict[str, pd.DataFrame]:
    """Per-epoch RMSE curves (eq. 9), one wide table per quantity: ``epoch``, ``<filter>_rmse_…``.

    Also ``sigma_x``: the true σ of the x measurement (sqrt of the mean drawn variance over runs,
    outliers included) beside each adaptive filter's mean σ̂_x = sqrt(mean R̂_xx).
    """
    d = res.data
    epoch = np.arange(d.K + 1)
    out = {}
    for name, (i, unit) in CURVES.items():
        tab = {"epoch": epoch}
        for key in res.runs:
            e, _ = _errors(res, key)
            tab[f"{key}_rmse_{name}_{unit.replace('/', 'p')}"] = np.sqrt((e[:, :, i] ** 2).mean(axis=0))
        out[f"rmse_{name}"] = pd.DataFrame(tab)
    tab = {"epoch": epoch, "true_sigma_x_m": np.sqrt(d.R_true[:, :, 0].mean(axis=0))}
    for key, fr in res.runs.items():
        if fr.R_hat is not None and key != "oracle-kf":
            sig = np.full(d.K + 1, np.nan)  # epoch 0 has no estimate
            sig[1:] = np.sqrt(fr.R_hat[~fr.diverged][:, 1:, 0].mean(axis=0))
            tab[f"{key}_sigma_hat_x_m"] = sig
    out["sigma_x"] = pd.DataFrame(tab)
    return out


def run(
    runs: int | None = None,
    seed: int = 1,
    outdir: Path | str | None = None,
    on_progress: Callable[[int, int], None] | None = None,
) -> pd.DataFrame:
    """Run both experiments with SKF, RRAE, RAKF, RSSHAKF, IRAKF (+ the oracle) -> tidy rows.

    ``outdir``: writes ``irakf_<experiment>_<curve>.csv`` (per-epoch RMSE of x position, x
    velocity, y position; σ̂_x against the true σ_x). ``on_progress(done, total)`` counts runs
    over both experiments.
    """
    runs = DEFAULT_RUNS if runs is None else runs
    rows: list[dict] = []
    tables: dict[str, pd.DataFrame] = {}
    total = 2 * runs if isinstance(runs, int) else 0
    for i, experiment in enumerate(EXPERIMENTS):
        spec = ExperimentSpec(scenario="cv2d", filters=FILTERS, runs=runs, seed=seed, outliers=experiment)
        prog = None
        if on_progress is not None:

            def prog(done: int, _total: int, off: int = i * runs) -> None:
                on_progress(off + done, total)

        res = run_experiment(spec, on_progress=prog, chunk_runs=max(1, runs // 5))
        rows += _experiment(res, experiment)
        for name, tab in curves(res).items():
            tables[f"irakf_{experiment}_{name}.csv"] = tab
    df = pd.DataFrame(rows)
    df["paper"] = df["paper"].astype(object).where(df["paper"].notna(), None)
    df["rel_diff"] = df["rel_diff"].astype(object).where(df["rel_diff"].notna(), None)
    outdir = ensure_dir(Path(outdir)) if outdir is not None else None
    if outdir is not None:
        for fname, tab in tables.items():
            tab.to_csv(outdir / fname, index=False)
    return df[COLUMNS]


register(
    Reproduction(
        key="irakf",
        title="IRAKF vs SKF, RRAE, RAKF, RSSHAKF on 2-D tracking with isolated / continuous outliers "
        "(Ge, Zhang, Tang 2020, §3)",
        paper=PAPER,
        run=run,
    )
)
