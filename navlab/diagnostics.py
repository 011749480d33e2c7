"""Explanations of the ways a filter is known to fail, one sentence each, with the number.

A student who sees the χ²-gated KF's error climb to 17 m after a few outliers concludes "gating is
bad"; what happened is a gate lock-out. :func:`explain` looks for the known failure mechanisms in a
finished :class:`~navlab.experiment.Results` and returns one :class:`Explanation` per filter and
mechanism found: the filter, the kind, the number that shows it, a sentence to print next to the
chart or table, and a link to the Learn page where the mechanism can be stepped through.

Kinds (the rule each one applies; thresholds are stated here and were not tuned to any result):

``lockout``
    Gate lock-out: in at least one run the filter rejected every measurement of
    ``LOCKOUT_MIN_EPOCHS`` or more consecutive epochs (flags 2/3 on every present channel) while
    its covariance of the headline error group grew at least ``LOCKOUT_P_GROWTH``-fold. Each
    rejection skips the update, P only grows by prediction, the error drifts, and the next
    innovation is even less plausible (ALGORITHMS.md §1.5). Ten chance rejections in a row have
    probability α¹⁰ = 1e-20 under the model at α = 0.01. Every run counts, diverged ones too (a
    lock-out is often why a run crosses the divergence bound), up to a non-finite state.
``runaway``
    Replacement run-away (NNMFUKF, ALGORITHMS.md §6.4 pitfall): in at least one run the measurement
    was replaced by a prediction (flag 4) on ``REPLACEMENT_CHAIN_MIN`` or more consecutive epochs;
    chained predictions integrate their errors like a random walk.
``band``
    R̂ held at a bound of its band (flag 6) on more than ``navlab.metrics.FLAG_SHOW_PCT`` % of the present
    measurements of the runs the filter is judged on (:func:`navlab.metrics.judge`, as the
    tables): the filters with an R̂ band (the Sage–Husa family, ``vb-akf``, ``hakf``) keep the
    eigenvalues of R0^-1/2 R̂ R0^-1/2 in [r_min, r_max] (ALGORITHMS.md §4.1 step 4; the VB filters
    per channel, §3.1). With a deliberate band (drive0708, own-drive: [0.25, 16]) R̂ there is the
    bound, not an estimate; the sentence says which bound and on what share (:func:`band_sides`).
``numerical_fix``
    Numerical fixes (flag 9: a covariance repaired to stay positive-definite) on more than
    ``navlab.metrics.FLAG_SHOW_PCT`` % of those measurements.
    Neither is ever an outlier detection.
``divergence``
    Runs the experiment marks as diverged (``FilterRun.diverged``); they are left out of the
    curves and the metrics.

Pure library code (no streamlit); the app shows :meth:`Explanation.markdown`, the CLI
:meth:`Explanation.to_dict`.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING
from urllib.parse import urlencode

import numpy as np

from navlab.errors import NavlabError
from navlab.filters.base import NUMERICAL_FIX, R_HAT_AT_BAND, REJECTED, REJECTED_AUX, REPLACED
from navlab.metrics import FLAG_SHOW_PCT

if TYPE_CHECKING:
    from navlab.experiment import FilterRun, Results

LOCKOUT_MIN_EPOCHS = 10  # consecutive epochs with every present measurement rejected
LOCKOUT_P_GROWTH = 2.0  # … while the headline group's variance grew at least this much
REPLACEMENT_CHAIN_MIN = 10  # consecutive epochs with a measurement replaced by a prediction

KINDS = ("lockout", "runaway", "band", "numerical_fix", "divergence")
#: the kinds that say what a share of flags means (divergence is shown apart, above the charts)
FLAG_KINDS = ("lockout", "runaway", "band", "numerical_fix")

LEARN_PAGE = "Learn"  # relative link: works from every page and under a server base path
# the Learn page's tiny example set to show each mechanism (its URL parameters)
LEARN_EXAMPLES: dict[str, dict[str, object]] = {
    # true noise 3× the assumed one: the gate rejects run after run while P grows (epochs 10–13
    # and 16–20 of the default seed)
    "lockout": {"ex_epochs": 20, "ex_noise": 3.0},
    # no outlier, smaller true noise: ννᵀ − HP⁻Hᵀ < 0 and R̂ is held at its band (flag 6) in the
    # first epochs
    "band": {"ex_epochs": 20, "ex_noise": 0.5, "ex_outk": 0, "ex_seed": 1},
    "numerical_fix": {},
    "runaway": {"ex_epochs": 30},
    "divergence": {},
}


@dataclass(frozen=True)
class Explanation:
    """One known failure of one filter in one experiment.

    filter, label : registry key and readable name of the filter.
    kind : one of :data:`KINDS`.
    value, unit : the number that shows it (e.g. 76 epochs of consecutive rejections).
    runs, of_runs : runs affected, runs in the experiment.
    sentence : one sentence saying what happened, with the numbers.
    learn : relative link to the Learn page showing the mechanism (``Learn?filter=…``).
    """

    filter: str
    label: str
    kind: str
    value: float
    unit: str
    runs: int
    of_runs: int
    sentence: str
    learn: str

    def markdown(self, link_text: str = "see how on Learn") -> str:
        """The sentence followed by a markdown link to the Learn page."""
        return f"{self.sentence} [{link_text}]({self.learn})"

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def learn_link(key: str, kind: str) -> str:
    """``Learn?filter=<key>&…``: the Learn page on ``key`` with the example showing ``kind``."""
    return f"{LEARN_PAGE}?" + urlencode({"filter": key, **LEARN_EXAMPLES.get(kind, {})})


def longest_run(b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of a (B, K) boolean array: (length, last index) of the longest run of True.

    Length 0 (last index 0) for a row without True; the first of equally long runs wins.
    """
    b = np.asarray(b, dtype=bool)
    B, K = b.shape
    if K == 0:
        return np.zeros(B, int), np.zeros(B, int)
    k = np.arange(K)
    last_false = np.maximum.accumulate(np.where(b, -1, k), axis=1)
    run = k - last_false  # length of the run of True ending at k (0 where False)
    end = run.argmax(axis=1)
    return run[np.arange(B), end], end


def _headline(res: Results) -> str:
    from navlab.scenarios import scenario_registry

    try:
        want = scenario_registry()[res.spec.scenario].headline
    except (KeyError, AttributeError):
        want = ()
    got = [g for g in want if g in res.data.groups]
    return got[0] if got else next(iter(res.data.groups))


def _error_norm(res: Results, fr: FilterRun, group: str, runs=slice(None), epochs=slice(None)):
    """Error norm of ``group`` on the chosen runs and epochs, or None without truth."""
    d = res.data
    if not getattr(d, "has_truth", True):
        return None
    idx = list(d.groups[group].idx)
    with np.errstate(invalid="ignore", over="ignore"):
        return np.linalg.norm(fr.x[runs, epochs][..., idx] - d.x_true[runs, epochs][..., idx], axis=-1)


def _g(v: float) -> str:
    """Three significant figures, without an exponent between 0.001 and 1e6 (5930, not 5.93e+03)."""
    v = float(v)
    if v != 0 and np.isfinite(v) and 1e-3 <= abs(v) < 1e6:
        return f"{float(f'{v:.3g}'):g}" if abs(v) < 1e5 else f"{float(f'{v:.3g}'):.0f}"
    return f"{v:.3g}"


def _runs(n: int, of: int) -> str:
    return f"{n} of {of} run" + ("" if of == 1 else "s")


def _any_flag(fr: FilterRun, *codes: int) -> bool:
    """Whether any run, epoch and channel of ``fr`` carries one of the flags ``codes``."""
    fl = fr.flags
    return any(bool((fl == c).any()) for c in codes)


def _lockout(res: Results, fr: FilterRun, group: str, judged: np.ndarray) -> Explanation | None:
    if not _any_flag(fr, REJECTED, REJECTED_AUX):  # nothing rejected: no epoch without a used one
        return None
    d = res.data
    present = np.isfinite(d.z[:, 1:])  # (B, K, m)
    fl = fr.flags[:, 1:]
    rejected = (fl == REJECTED) | (fl == REJECTED_AUX) | ~present
    rej_epoch = rejected.all(axis=2) & present.any(axis=2)  # (B, K): nothing used at epoch k+1
    # every run counts (a lock-out is often why a run diverges), up to a non-finite state
    rej_epoch &= np.isfinite(fr.x[:, 1:]).all(axis=2)
    length, end = longest_run(rej_epoch)
    start = end - length + 1  # in epochs 1…K: epoch = index + 1
    idx = list(d.groups[group].idx)
    P = fr.P_diag[..., idx].sum(axis=-1)  # (B, K+1)
    b = np.arange(d.B)
    p_before = P[b, np.maximum(start, 0)]  # posterior just before the first rejection
    p_end = P[b, end + 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        growth = p_end / p_before
    locked = (length >= LOCKOUT_MIN_EPOCHS) & (growth >= LOCKOUT_P_GROWTH)
    if not locked.any():
        return None
    r = int(np.argmax(np.where(locked, length, -1)))  # the longest lock-out
    e0, e1 = int(start[r]) + 1, int(end[r]) + 1
    g = d.groups[group]
    n = int(locked.sum())
    s = (
        f"{fr.label} — gate lock-out in {_runs(n, d.B)}: the gate rejected every measurement for "
        f"{int(length[r])} consecutive epochs (t = {_g(d.t[e0])}–{_g(d.t[e1])} s) while the "
        f"{g.label} variance (trace of P) grew from {_g(p_before[r])} to {_g(p_end[r])} {g.unit}²"
    )
    err = _error_norm(res, fr, group, r, slice(e0, None))  # that run, from the lock-out on
    if err is not None and np.isfinite(err).any():
        k = e0 + int(np.nanargmax(err))
        s += f", so the error in that run reached {_g(err[k - e0])} {g.unit}"
        if judged.any():  # the RMSE curve is drawn over the judged runs
            at_k = _error_norm(res, fr, group, judged, k)
            with np.errstate(invalid="ignore"):
                rmse = float(np.sqrt(np.nanmean(at_k**2)))
            s += f" (the RMSE curve at t = {_g(d.t[k])} s: {_g(rmse)} {g.unit})"
    return Explanation(
        fr.key,
        fr.label,
        "lockout",
        float(length[r]),
        "epochs",
        n,
        d.B,
        s + ".",
        learn_link(fr.key, "lockout"),
    )


def _runaway(res: Results, fr: FilterRun, group: str) -> Explanation | None:
    from navlab.filters import registry

    if not _any_flag(fr, REPLACED):  # no replacement: no chain of them
        return None
    d = res.data
    replaced = (fr.flags[:, 1:] == REPLACED).any(axis=2)
    length, _ = longest_run(replaced)
    hit = length >= REPLACEMENT_CHAIN_MIN
    if not hit.any():
        return None
    n = int(hit.sum())
    g = d.groups[group]
    s = (
        f"{fr.label} — replacement run-away in {_runs(n, d.B)}: the measurement was replaced by "
        f"the prediction for up to {int(length.max())} consecutive epochs, and chained "
        "predictions integrate their errors like a random walk"
    )
    err = _error_norm(res, fr, group, hit)  # the runs with a chain
    if err is not None:
        with np.errstate(invalid="ignore"):
            peak = np.nanmax(np.where(np.isfinite(err), err, np.nan), axis=1)
        s += f"; the {g.label} error reached {_g(np.nanmax(peak))} {g.unit}"
        if n > 1:
            s += f" (median over those runs {_g(np.nanmedian(peak))} {g.unit})"
    guarded = f"{fr.key}-guarded"
    if guarded in registry() and guarded not in (fr.key,):
        s += f"; `{guarded}` caps the chain"
    return Explanation(
        fr.key,
        fr.label,
        "runaway",
        float(length.max()),
        "epochs",
        n,
        d.B,
        s + ".",
        learn_link(fr.key, "runaway"),
    )


def band_sides(trace: np.ndarray, m: int, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Which bound of the band [lo, hi] a clamped R̂ can be held at, from tr(R0⁻¹ R̂) alone.

    After the clamp the eigenvalues λ of C = R0^-1/2 R̂ R0^-1/2 lie in [lo, hi], one of them at a
    bound. λ_max = hi needs tr C ≥ hi + (m − 1)·lo; λ_min = lo needs tr C ≤ lo + (m − 1)·hi; and
    by Schur–Horn any trace in between fits either (the stored R̂ is its diagonal only, whose sum
    is tr C when R0 is diagonal). Returns the boolean arrays (lower possible, upper possible).
    """
    tol = 1e-6 * max(hi, 1.0)
    return trace <= lo + (m - 1) * hi + tol, trace >= hi + (m - 1) * lo - tol


def _band(res: Results, key: str) -> tuple[float, float] | None:
    """The band [r_min, r_max] filter ``key`` ran with (spec, then scenario preset, then class)."""
    from navlab.experiment import filter_group

    try:
        g = filter_group(res.spec, key)
        p = {**g.defaults(), **g.values}
        return float(p["r_min"]), float(p["r_max"])
    except (NavlabError, KeyError, TypeError, ValueError):  # no band (r_min, r_max) to read
        return None


def _band_sentence(
    res: Results,
    fr: FilterRun,
    ok: np.ndarray,
    held: np.ndarray,
    present,
    band: tuple[float, float],
    sage_husa: bool = True,
) -> str:
    """Flag 6 of a filter with an R̂ band (the Sage–Husa family, the VB filters): at which bound
    R̂ was held, on what share of the measurements.
    """
    d = res.data
    R0 = np.atleast_2d(np.asarray(d.model.R0, dtype=float))
    pct = 100.0 * float(held[present].mean())
    tail = (
        ": there R̂ is the bound, not an estimate. These are not outlier detections; the band is "
        "the filter's r_min, r_max (ALGORITHMS.md §3.1, §4.1 step 4)."
    )
    generic = f"{fr.label} — R̂ held at a bound of its band (flag 6) on {_g(pct)} % of the measurements"
    if fr.R_hat is None or not np.allclose(R0, np.diag(np.diag(R0))):
        return generic + tail
    lo, hi = band
    with np.errstate(invalid="ignore", divide="ignore"):
        tr = np.sum(fr.R_hat[ok, 1:] / np.diag(R0), axis=-1)  # (runs, K): tr(R0⁻¹ R̂) per epoch
    finite = np.isfinite(tr)
    low, up = band_sides(np.where(finite, tr, 0.0), R0.shape[0], lo, hi)
    low, up = low & finite, up & finite
    fx = held & present
    n_present = int(present.sum())

    def share(epochs: np.ndarray) -> float:
        return 100.0 * float((fx & epochs[..., None]).sum()) / n_present

    found = [
        (share(low & ~up), f"the lower bound r_min = {_g(lo)} × R0 (σ {_g(np.sqrt(lo))}× the nominal σ)"),
        (share(up & ~low), f"the upper bound r_max = {_g(hi)} × R0 (σ {_g(np.sqrt(hi))}× the nominal σ)"),
        (share(low & up), f"one bound of [{_g(lo)}, {_g(hi)}] × R0 (which one, the stored R̂ does not tell)"),
        (share(~finite), "no finite value (a diverged run)"),
    ]
    parts = [f"{what} on {_g(v)} %" for v, what in found if v > 0]
    if not parts:
        return generic + tail
    s = f"{fr.label} — R̂ held at " + ", at ".join(parts) + " of the measurements (flag 6)"
    if found[0][0] > 0 and sage_husa:
        s += (
            "; at the lower bound the update (1 − d)R̂ + d(ννᵀ − HP⁻Hᵀ) fell below r_min × R0 "
            "along some direction"
        )
    return s + (
        ", and along that direction R̂ is the bound, not an estimate. These are not outlier "
        "detections; the band is the filter's r_min, r_max (ALGORITHMS.md §3.1, §4.1 step 4)."
    )


def _flag_share(
    res: Results, fr: FilterRun, ok: np.ndarray, code: int
) -> tuple[np.ndarray, np.ndarray] | None:
    """Where flag ``code`` stands (runs judged, epochs 1…K, channels) and the present measurements,
    when it stands on more than ``navlab.metrics.FLAG_SHOW_PCT`` % of them; else None.
    """
    if not _any_flag(fr, code):  # 0 % of the measurements
        return None
    present = np.isfinite(res.data.z[ok, 1:])
    flagged = fr.flags[ok, 1:] == code
    if not present.any() or 100.0 * float(flagged[present].mean()) <= FLAG_SHOW_PCT:
        return None
    return flagged, present


def _explanation(
    fr: FilterRun, ok: np.ndarray, kind: str, flagged: np.ndarray, present, s: str
) -> Explanation:
    pct = 100.0 * float(flagged[present].mean())
    n = int(flagged.any(axis=(1, 2)).sum())
    return Explanation(fr.key, fr.label, kind, pct, "%", n, int(ok.sum()), s, learn_link(fr.key, kind))


def _band_held(res: Results, fr: FilterRun, ok: np.ndarray) -> Explanation | None:
    from navlab.filters import registry

    found = _flag_share(res, fr, ok, R_HAT_AT_BAND)
    if found is None:
        return None
    held, present = found
    cls = registry().get(fr.key)
    band = _band(res, fr.key) if cls is not None else None
    if band is None:  # a filter whose band navlab cannot read (a plug-in's own parameters)
        s = (
            f"{fr.label} — R̂ held at a bound of its band (flag 6) on "
            f"{_g(100.0 * float(held[present].mean()))} % of the measurements: there R̂ is the "
            "bound, not an estimate. These are not outlier detections."
        )
    else:
        sage_husa = cls.__module__.startswith("navlab.filters.sage_husa")
        s = _band_sentence(res, fr, ok, held, present, band, sage_husa)
    return _explanation(fr, ok, "band", held, present, s)


def _numerical_fix(res: Results, fr: FilterRun, ok: np.ndarray) -> Explanation | None:
    found = _flag_share(res, fr, ok, NUMERICAL_FIX)
    if found is None:
        return None
    fixed, present = found
    s = (
        f"{fr.label} — needed a numerical fix (flag 9: a covariance repaired to stay positive-"
        f"definite) on {_g(100.0 * float(fixed[present].mean()))} % of the measurements; these are "
        "not outlier detections."
    )
    return _explanation(fr, ok, "numerical_fix", fixed, present, s)


def _divergence(res: Results, fr: FilterRun) -> Explanation | None:
    d = res.data
    bad = np.asarray(fr.diverged)
    n = int(bad.sum())
    if n == 0:
        return None
    at = np.asarray(fr.diverged_at)[bad]
    k = int(at[at >= 0].min()) if (at >= 0).any() else 0
    s = (
        f"{fr.label} — {_runs(n, d.B)} diverged (the first at epoch {k}, t = {_g(d.t[k])} s); "
        "they are left out of the curves and the table."
    )
    return Explanation(
        fr.key, fr.label, "divergence", float(n), "runs", n, d.B, s, learn_link(fr.key, "divergence")
    )


def explain(res: Results, kinds: tuple[str, ...] = KINDS) -> list[Explanation]:
    """The known failures found in ``res``: per filter (in ``res.runs`` order), per kind (in
    :data:`KINDS` order). A filter that fails in none of these ways gets no explanation.
    """
    unknown = set(kinds) - set(KINDS)
    if unknown:
        raise ValueError(f"unknown kinds {sorted(unknown)}; known: {', '.join(KINDS)}")
    if res.data.K == 0:
        return []
    from navlab.metrics import judge

    group = _headline(res)
    jd = judge({k: fr.diverged for k, fr in res.runs.items()})  # the runs the curves and tables use
    out: list[Explanation] = []
    for fr in res.runs.values():
        found = {
            "lockout": lambda fr=fr: _lockout(res, fr, group, jd.judged[fr.key]),
            "runaway": lambda fr=fr: _runaway(res, fr, group),
            "band": lambda fr=fr: _band_held(res, fr, jd.judged[fr.key]),
            "numerical_fix": lambda fr=fr: _numerical_fix(res, fr, jd.judged[fr.key]),
            "divergence": lambda fr=fr: _divergence(res, fr),
        }
        for kind in KINDS:
            if kind in kinds:
                e = found[kind]()
                if e is not None:
                    out.append(e)
    return out


# ------------------------------------------------------------------------ what an R̂ chart shows

#: σ̂ "reaches" the true σ when the median over the runs is within this fraction of it
REACH_TOL = 0.2
#: a schedule whose σ stays within this factor of its first value is "constant"
CONSTANT_WITHIN = 1.05


def rhat_sentence(res: Results, channel: int) -> str:
    """One sentence, computed from the run, saying what the R̂ chart of ``channel`` shows.

    The filters read are those that estimate R (the oracle, which is handed the truth, is left
    out), on the runs each is judged on, through the median σ̂(t) = √median R̂ over those runs.
    A schedule that changes: after the epoch where the true σ has made half of its largest change
    (a step: the step), the time until each filter's median σ̂ first comes within ``REACH_TOL`` of
    the true σ, fastest first, and where it ends for those that never do. A constant schedule: the
    median |σ̂/σ − 1| over the analysis window, closest first. '' when no filter estimates R.
    """
    from navlab.filters import registry
    from navlab.metrics import summary

    d = res.data
    reg = registry()
    judged = summary(res).judgement.judged
    sigma = np.sqrt(d.R_schedule[:, channel])
    name = d.channel_names[channel] if channel < len(d.channel_names) else str(channel)
    curves = {}
    for key, fr in res.runs.items():
        cls = reg.get(key)
        if fr.R_hat is None or (cls is not None and cls.family == "oracle") or not judged[key].any():
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an epoch with no finite R̂: NaN
            curves[fr.label] = np.sqrt(np.nanmedian(fr.R_hat[judged[key], :, channel], axis=0))
    if not curves:
        return ""
    dev = np.abs(np.log(sigma[1:] / sigma[1]))
    if dev.max() <= np.log(CONSTANT_WITHIN):
        W = np.asarray(d.window, bool)
        W[0] = False
        err = {lab: float(np.nanmedian(np.abs(c[W] / sigma[W] - 1))) for lab, c in curves.items()}
        order = sorted(err, key=lambda lab: (np.isnan(err[lab]), err[lab]))
        parts = [f"{lab} {_g(100 * err[lab])} %" for lab in order]
        return (
            f"The true σ of channel {name} is constant; the median σ̂ is off by (median over the "
            "analysis window): " + ", ".join(parts) + "."
        )
    k_half = 1 + int(np.argmax(dev >= dev.max() / 2))
    t_c = float(d.t[k_half])
    ratio = sigma[k_half] / sigma[k_half - 1]
    change = (
        f"{_g(ratio)}× at t = {_g(t_c)} s" if abs(np.log(ratio)) >= dev.max() / 2 else f"by t = {_g(t_c)} s"
    )
    reached, never = [], []
    for lab, c in curves.items():
        with np.errstate(invalid="ignore"):
            near = np.abs(c[k_half:] / sigma[k_half:] - 1) <= REACH_TOL
        if near.any():
            reached.append((float(d.t[k_half + int(np.argmax(near))]) - t_c, lab))
        else:
            last = c[-1] / sigma[-1]
            never.append(f"{lab}, ending at {_g(last)}× the true σ" if np.isfinite(last) else lab)
    parts = [f"{lab} {f'after {_g(lag)} s' if lag > 0 else 'at once'}" for lag, lab in sorted(reached)]
    s = f"The true σ of channel {name} changes ({change}); each filter's median σ̂ comes within "
    s += f"{int(100 * REACH_TOL)} % of it: " + ("; ".join(parts) if parts else "none does")
    if never:
        s += ("; never: " if parts else " — ") + "; ".join(never)
    return s + "."
