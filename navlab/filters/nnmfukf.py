"""NNMFUKF: RBF-network-aided multiple-fading-factor SVD-UKF (ALGORITHMS.md §6; S2 §2.3–2.4, Fig. 1).

Tan, Wang, Zhao, "RBF-neural-network-aided multiple-fading-factor adaptive SVD-UKF for GPS/INS",
Acta Geodaetica et Cartographica Sinica 44(4): 384–391, 2015 (S2).

Per epoch (S2 Fig. 1 steps 1–4): SVD-UKF prediction and the χ² test of §5; if the test passes, an
ordinary update (and, inside the training window, a training pair for the network); if it fails and
the network is trained, the GPS observation is replaced by the network's prediction
``ĝ_k = g_{k−1}^used + ŷ(u_k)`` (z'_k = r_k − ĝ_k, R'_ii = max(R_ii, σ²_NN,i)), and the fading factors
of §5 are then computed from the replaced residual.

What the network sees comes from two optional hooks of the scenario's model (the GPS/INS scenario
``gps-ins-rtk`` provides both):

* ``model.nn_features(x_prev, k) -> (B, d)``: the input u_k from the corrected navigation solution at
  k−1 (``x_prev`` = the filter's own x̂⁺_{k−1}) and the IMU increments over (t_{k−1}, t_k] (§6.1);
* ``model.nn_reference(k) -> (B, m)``: the INS-side value r_k of each measured quantity, so that the
  raw GPS value is g_k = r_k − z_k (z = INS − GPS).

Without them the network learns z itself (r = 0, so it predicts increments of −z) from the filter's
previous estimate x̂⁺_{k−1}: a generic fallback for other models, not S2's design.

RECONSTRUCTION (§5, §6, §10 items 20–28): S2's equations are lost; clustering radius, J range, width
search and R' are navlab's readings.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from navlab.filters.base import (
    EPOCH_ANOMALY,
    REPLACED,
    KFLimit,
    Model,
    SideInfo,
    StepOut,
    Teaching,
    flag_fix,
    register,
)
from navlab.filters.rbf import RBFNet, train
from navlab.filters.ukf import CHI2_TEST, Measured, MFUKFParams, UKFState, _FadingBase
from navlab.linalg import Array
from navlab.params import param


class NNState(NamedTuple):
    """UKF state + what the network needs. Shapes: (B, …)."""

    x: Array
    P: Array
    chi: Array | None
    neg: Array | None
    x_prev: Array  # x̂⁺_{k−1} (set by predict)
    g_prev: Array  # (B, m) GPS value used at k−1 (raw or predicted)
    pass_prev: Array  # (B,) χ² test passed at k−1
    buf_u: tuple[Array, ...] | None  # last W training inputs (B, d), chronological
    buf_y: tuple[Array, ...] | None  # training targets (B, m) (0 where inadmissible)
    buf_ok: tuple[Array, ...] | None  # admissible (B,)
    net: RBFNet | None
    run_len: Array  # (B,) consecutive replaced epochs


class Replaced(NamedTuple):
    """What §6's network step hands to the fading update: the state (buffers, network), the
    residual V and noise R (replaced channels: V', R'), the test's verdict, the replaced channels
    (B, m) and the GPS value g_k kept for the next epoch (raw or predicted; None: no network).
    """

    state: Any
    V: Array
    R: Array
    reject: Array
    mask: Array
    g: Array | None


@dataclass(frozen=True)
class NNMFUKFParams(MFUKFParams):
    """NNMFUKF options (ALGORITHMS.md §6, §10 items 24–28)."""

    use_network: bool = param(True, help="off: the filter is exactly the MFUKF")
    mode: str = param(
        "frozen",
        choices=("frozen", "online"),
        help="frozen: train once at the end of the window (S2 experiment); online: also refit on a "
        "sliding window of admissible pairs (S2 §2.4 step 3)",
    )
    train_start: int = param(200, lo=1, hi=10**7, help="first epoch of the training window (S2: 200 s)")
    train_end: int = param(600, lo=2, hi=10**7, help="epoch at which the network is trained (S2: 600 s)")
    window: int = param(400, lo=10, hi=100000, help="online mode: sliding window of training pairs")
    retrain_every: int = param(10, lo=1, hi=100000, help="online mode: refit every this many epochs")
    j_min: int = param(10, lo=1, hi=1000, help="fewest RBF centres")
    j_max: int = param(100, lo=1, hi=1000, help="most RBF centres")
    ridge: float = param(1e-6, lo=0.0, hi=1e3, help="ridge λ of the output weights (standardised units)")
    linear_tail: str = param(
        "off",
        choices=("off", "on", "auto"),
        help="navlab option: add a linear term to the RBF output (auto: per output, chosen on the "
        "hold-out); S2's network has none",
    )
    width_per_output: bool = param(
        False, help="navlab option: search the kernel width separately for each output"
    )
    clip_inputs: bool = param(
        False, help="navlab guard: clip the network's inputs to their training range (no extrapolation)"
    )
    min_pairs: int = param(20, lo=2, hi=100000, help="train only with at least this many admissible pairs")
    replace: str = param(
        "all",
        choices=("all", "flagged"),
        help="all: replace the whole observation (S2); flagged: only channels with "
        "|V_i|/√Pyy_ii > c_replace (navlab option)",
    )
    c_replace: float = param(3.0, lo=0.5, hi=100.0, help="per-channel replacement gate (flagged mode)")
    max_run: int = param(
        0,
        lo=0,
        hi=100000,
        help="0: no limit (S2); n: after n consecutive replaced epochs use the raw observation once",
    )
    retest_after_replace: bool = param(
        False, help="skip the fading factors when the replaced residual passes the χ² test"
    )


@register
class NNMFUKF(_FadingBase):
    """MFUKF whose rejected GPS observations are replaced by an RBF network's prediction (§6.4).

    Stats per step: ``gamma``, ``gamma_threshold``, ``fading`` (B, m), ``rejected``, ``replaced``
    (B,), ``run_len`` (consecutive replacements), ``nn_trained``; flag 4 on replaced channels, 5 on
    rejected epochs left unreplaced, 9 on numerical repairs; ``R_used`` is R' on replaced epochs.
    """

    key = "nnmfukf"
    label = "NNMFUKF"
    family = "robust-adaptive"
    spec_section = "§6"
    reconstruction = True
    summary = (
        "MFUKF plus an RBF neural network trained on clean epochs: when the χ² test fails it "
        "replaces the GPS observation by the network's prediction, then fades what remains."
    )
    Params = NNMFUKFParams
    kf_limit = KFLimit(
        {"xi": 1e12, "use_network": False},
        linear_only=True,
        why="no network and a test that never fails: the SVD-UKF, the KF on a linear model",
    )
    teaching = Teaching(
        idea=(
            "Tan et al.'s proposal: when the χ² test fails, first replace the GPS observation by "
            "the prediction of an RBF neural network trained on IMU increments during normal "
            "epochs, then let the fading factors absorb what remains. It needs an INS and a "
            "trained network, so it runs only on the GPS/INS scenario."
        ),
        equations=(
            r"\Psi_j(u) = \exp\!\left(-\dfrac{\|u - C_j\|^2}{2 s_w^2}\right), \qquad "
            r"\hat y(u) = \sum_j W_j \Psi_j(u) + b",
            r"\gamma > \xi\varepsilon \Rightarrow \hat p^{GPS}_k = p^{GPS}_{k-1} + \hat d_k[0{:}3], "
            r"\quad z'_k = p^{INS}_k - \hat p^{GPS}_k \ (\text{and velocity})",
            r"R'_{ii} = \max(R_{ii}, \sigma^2_{NN,i}), \qquad "
            r"\sigma_i = \max\!\left(1, \dfrac{V_i'^2 - R'_{ii}}{A_{ii}}\right)",
        ),
        caveat=(
            "On the tiny example the RBF network is never trained (it needs IMU increments and "
            "hundreds of clean epochs), so a failed χ² test falls back to the fading factors: the "
            "steps are those of the MFUKF."
        ),
    )

    def _init_state(self, model: Model, x0: Array, P0: Array) -> Any:
        p = self.params
        if p.train_end <= p.train_start:
            from navlab.errors import NavlabError

            raise NavlabError(
                f"nnmfukf: train_end ({p.train_end}) must be after train_start ({p.train_start})"
            )
        if p.j_min > p.j_max:
            from navlab.errors import NavlabError

            raise NavlabError(f"nnmfukf: j_min ({p.j_min}) must not exceed j_max ({p.j_max})")
        B = x0.shape[0]
        m = np.asarray(model.R0).shape[-1]
        return NNState(
            x=x0,
            P=P0,
            chi=None,
            neg=None,
            x_prev=x0,
            g_prev=np.full((B, m), np.nan),
            pass_prev=np.zeros(B, dtype=bool),
            buf_u=None,
            buf_y=None,
            buf_ok=None,
            net=None,
            run_len=np.zeros(B, dtype=int),
        )

    def predict(self, model: Model, state: NNState, k: int) -> NNState:
        x_prev = state.x
        state = super().predict(model, state, k)
        return state._replace(x_prev=x_prev)

    # -- network hooks --------------------------------------------------------------------
    @staticmethod
    def _features(model: Model, x_prev: Array, k: int) -> Array:
        fn = getattr(model, "nn_features", None)
        return np.asarray(fn(x_prev, k), dtype=float) if fn is not None else x_prev

    @staticmethod
    def _reference(model: Model, k: int, z: Array) -> Array:
        fn = getattr(model, "nn_reference", None)
        return np.asarray(fn(k), dtype=float) if fn is not None else np.zeros_like(z)

    def _buffer_len(self) -> int:
        p = self.params
        if p.mode == "online":
            return int(p.window)
        return int(p.train_end - p.train_start + 1)

    def _store(self, st: NNState, u: Array, y: Array, adm: Array) -> NNState:
        """Append one (possibly inadmissible) pair per run to the chronological buffers (tuples of
        per-epoch arrays, stacked only when the network is trained: no copy of the window per step).
        """
        W = self._buffer_len()
        bu = (*(st.buf_u or ()), u)[-W:]
        by = (*(st.buf_y or ()), np.where(adm[:, None], y, 0.0))[-W:]
        bo = (*(st.buf_ok or ()), adm)[-W:]
        return st._replace(buf_u=bu, buf_y=by, buf_ok=bo)

    def _train(self, st: NNState, refit: bool) -> NNState:
        p = self.params
        if st.buf_u is None:
            return st
        old = st.net if (refit and st.net is not None) else None
        linear = {"off": False, "on": True, "auto": "auto"}[p.linear_tail]
        net = train(
            np.stack(st.buf_u, axis=1),
            np.stack(st.buf_y, axis=1),
            np.stack(st.buf_ok, axis=1),
            j_min=p.j_min,
            j_max=p.j_max,
            lam=p.ridge,
            min_samples=p.min_pairs,
            s_w=None if old is None else old.s_w,
            linear=linear,
            per_output=p.width_per_output,
            lin_on=None if old is None else old.lin_on,
            clip=p.clip_inputs,
        )
        if refit and st.net is not None:
            # keep σ_NN from the full search (a refit has no hold-out) and never untrain a run
            net = RBFNet(**{**net.__dict__, "sigma_nn": st.net.sigma_nn})
            keep = ~net.trained & st.net.trained
            if keep.any():
                net = _merge(net, st.net, keep)
        return st._replace(net=net)

    # -- the step -------------------------------------------------------------------------
    def update(self, model: Model, state: NNState, k: int, z: Array, side: SideInfo):
        p = self.params
        ms = self._measure(model, state, k, z)  # 1  ẑ⁻, V, A, Pxy, γ against ξε
        rp = Replaced(state, ms.V, ms.R, ms.reject, np.zeros(z.shape, dtype=bool), None)  # no network
        if p.use_network:
            ref = self._reference(model, k, z)
            st, u = self._learn(model, state, k, ref - z, ms.reject)  # §6.1 pairs, training
            rp = self._replace(model, st, u, k, z, ref, ms)  # 3  (§6.3) z' from the network
        x, P, Pyy, fixed, sig = self._fade(model, state, k, ms, rp.V, rp.R, rp.reject)  # 2–3  σ_i, update
        flags = np.zeros(z.shape, dtype=np.int8)
        flags[rp.reject[:, None] & ms.ok] = EPOCH_ANOMALY
        flags[rp.mask & ms.ok] = REPLACED
        flag_fix(flags, fixed | ms.neg)
        net = rp.state.net
        trained = net.trained if net is not None else np.zeros(z.shape[0], dtype=bool)
        replaced = rp.mask.any(axis=1)
        run_len = np.where(replaced, state.run_len + 1, 0)
        stats = {
            "gamma": ms.gamma,
            "gamma_threshold": ms.threshold,
            "fading": sig,
            "rejected": rp.reject.astype(float),
            "replaced": replaced.astype(float),
            "run_len": run_len.astype(float),
            "nn_trained": trained.astype(float),
        }
        out = StepOut(x=x, P=P, innov=rp.V, S=Pyy, R_used=rp.R, flags=flags, stats=stats)
        g_prev = rp.g if rp.g is not None else state.g_prev
        new = rp.state._replace(
            x=x, P=P, chi=None, neg=None, g_prev=g_prev, pass_prev=~rp.reject, run_len=run_len
        )
        return new, out

    def _learn(
        self, model: Model, state: NNState, k: int, g: Array, reject: Array
    ) -> tuple[NNState, Array | None]:
        """§6.1: the training pair (u_k, g_k − g_{k−1}) of every run, admissible if epochs k−1 and k
        both passed the test, into the buffers; the network trained at ``train_end`` (and, online,
        refitted every ``retrain_every`` epochs). Returns the state and the input u_k (None where
        no step needs it).
        """
        p = self.params
        collecting = k >= p.train_start and (k <= p.train_end or p.mode == "online")
        if not (collecting or (state.net is not None and reject.any())):
            return state, None  # the network's input is needed only to collect or to replace
        u = self._features(model, state.x_prev, k)
        if not collecting:
            return state, u
        y = g - state.g_prev
        adm = ~reject & state.pass_prev & np.all(np.isfinite(y), -1) & np.all(np.isfinite(u), -1)
        st = self._store(state, u, y, adm)
        if k == p.train_end:
            st = self._train(st, refit=False)
        elif p.mode == "online" and k > p.train_end and (k - p.train_end) % p.retrain_every == 0:
            st = self._train(st, refit=True)
        return st, u

    def _replace(
        self, model: Model, st: NNState, u: Array | None, k: int, z: Array, ref: Array, ms: Measured
    ) -> Replaced:
        """3  (§6.3) On a rejected epoch of a run with a trained network, the observation replaced by
        the network's: ĝ_k = g_{k−1} + NN(u_k), z' = ref − ĝ_k, R'_ii = max(R_ii, σ²_NN,i),
        V' = z' − ẑ⁻ (``replace="flagged"``: only the channels with |V_i|/√Pyy_ii > c_replace).
        """
        p, (B, m) = self.params, z.shape
        g = ref - z  # raw GPS values (NaN where missing)
        none = Replaced(st, ms.V, ms.R, ms.reject, np.zeros((B, m), dtype=bool), g)
        use = ms.reject & st.net.trained if st.net is not None else ms.reject & False
        if p.max_run > 0:
            use &= st.run_len < p.max_run
        if not use.any():
            return none
        if u is None:
            u = self._features(model, st.x_prev, k)
        g_hat = st.g_prev + st.net.predict(u)
        z_rep = ref - g_hat
        rep = use[:, None] & ms.ok & np.isfinite(z_rep)
        R_d = np.diagonal(ms.R, axis1=-2, axis2=-1)
        if p.replace == "flagged":
            rep &= np.abs(ms.V) > p.c_replace * np.sqrt(np.diagonal(ms.A, axis1=-2, axis2=-1) + R_d)
        if not rep.any():
            return none._replace(mask=rep)
        r_new = np.where(rep, np.maximum(R_d, st.net.sigma_nn**2), R_d)
        R = ms.R + (r_new - R_d)[:, :, None] * np.eye(m)  # R'_ii = max(R_ii, σ²_NN,i)
        V = np.where(ms.ok, np.where(rep, z_rep, z) - ms.z_hat, 0.0)  # V' = z' − ẑ⁻
        reject = ms.reject
        if p.retest_after_replace:  # option: no fading where the replaced V' passes
            i = np.flatnonzero(rep.any(axis=1))
            _, _, rej2 = CHI2_TEST((V[i], ms.A[i], R[i], ms.ok[i]), self._test(m))
            reject = reject.copy()
            reject[i] &= rej2
        return Replaced(st, V, R, reject, rep, np.where(rep, g_hat, g))


@dataclass(frozen=True)
class NNMFUKFGuardedParams(NNMFUKFParams):
    """NNMFUKF with navlab's guards on (same options, other defaults)."""

    linear_tail: str = param(
        "auto",
        choices=("off", "on", "auto"),
        help="add a linear term to the RBF output (auto: per output, chosen on the hold-out)",
    )
    width_per_output: bool = param(True, help="search the kernel width separately for each output")
    clip_inputs: bool = param(True, help="clip the network's inputs to their training range")
    replace: str = param(
        "flagged",
        choices=("all", "flagged"),
        help="all: replace the whole observation (S2); flagged: only channels with |V_i|/√Pyy_ii > c_replace",
    )
    max_run: int = param(
        3,
        lo=0,
        hi=100000,
        help="after this many consecutive replaced epochs use the raw observation once (0: never)",
    )


@register
class NNMFUKFGuarded(NNMFUKF):
    """NNMFUKF with navlab's guards against the failure modes found in the S2 scenario.

    Same algorithm and options as ``nnmfukf``; only the defaults differ. The faithful §6 filter
    locks out in ``gps-ins-rtk``: one poor network prediction (the 600–615 s right turn at 14 m/s
    and the disturbed Δv_z input lie outside the training data) is amplified by the fading factors
    computed after the replacement, the next raw GPS then fails the χ² test, so it is replaced
    again from a chain of predictions whose inputs (the corrected velocity) are already wrong. The
    guards: inputs clipped to the training range, a linear term in the network where the hold-out
    prefers it and a width per output, replacement of the flagged channels only, and the raw
    observation after 3 consecutive replacements. Not in S2; a navlab variant.
    """

    key = "nnmfukf-guarded"
    label = "NNMFUKF (guarded)"
    summary = (
        "NNMFUKF with navlab's guards: per-channel replacement, a cap on consecutive "
        "replacements, a network that does not extrapolate wildly."
    )
    Params = NNMFUKFGuardedParams


def _merge(a: RBFNet, b: RBFNet, take_b: Array) -> RBFNet:
    """Per-run choice between two networks (both padded to the same J_max by :func:`train`)."""
    out = {}
    for name, va in a.__dict__.items():
        vb = b.__dict__[name]
        if not isinstance(va, np.ndarray) or not isinstance(vb, np.ndarray):
            out[name] = va  # flags (linear) and optional arrays absent from one of them
            continue
        sel = take_b.reshape((-1,) + (1,) * (np.ndim(va) - 1))
        out[name] = np.where(sel, vb, va)
    return RBFNet(**out)


__all__ = ["NNMFUKF", "NNMFUKFGuarded", "NNMFUKFGuardedParams", "NNMFUKFParams", "NNState", "UKFState"]
