"""Noise schedules: the true measurement-noise standard deviation σ(t) per channel.

A schedule turns a scenario's nominal σ (what the filters assume) into the true σ_k used to draw
the noise at every epoch k = 0 … K; the scenario records R(t) = σ_k² as ground truth, so every
adaptive filter's R̂ can be compared with it. Times are given as fractions of the run (0 = first
epoch, 1 = last) so one schedule fits every scenario; ``channels`` selects which channels change
(empty = all).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from navlab import params as P_
from navlab.errors import NavlabError
from navlab.linalg import Array
from navlab.params import MAX_EPOCHS, param
from navlab.registry import Registry

_CH_HELP = "channel indices that follow the schedule (empty = all channels)"


class Schedule:
    """Base class: ``factor(u, m)`` returns the σ multiplier (K+1, m) at run fractions ``u``."""

    key: ClassVar[str] = ""
    label: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    Params: ClassVar[type] = P_.NoParams

    def __init__(self, params: Any = None) -> None:
        if params is None or isinstance(params, dict):
            params = P_.build(self.Params, params, f"noise schedule '{self.key}'")
        self.params = params

    def factor(self, u: Array, k: Array, m: int) -> Array:
        raise NotImplementedError

    def std(self, nominal_std: Array, K: int) -> Array:
        """True σ (K+1, m) for epochs 0 … K given the nominal σ (m,)."""
        nominal_std = np.asarray(nominal_std, dtype=float)
        m = nominal_std.shape[0]
        k = np.arange(K + 1, dtype=float)
        u = k / max(K, 1)
        f = np.broadcast_to(self.factor(u[:, None], k[:, None], m), (K + 1, m)).copy()
        chans = getattr(self.params, "channels", ())
        if chans:
            bad = [c for c in chans if not 0 <= int(c) < m or int(c) != c]  # 0.5 was channel 0
            if bad:
                raise NavlabError(
                    f"noise schedule '{self.key}': channel(s) {bad} do not exist; "
                    f"this scenario has channels 0 … {m - 1} (whole numbers)"
                )
            keep = np.ones(m, dtype=bool)
            keep[[int(c) for c in chans]] = False
            f[:, keep] = 1.0
        return nominal_std * f


#: Every noise schedule, by key, in the order they are offered.
SCHEDULES: Registry[type[Schedule]] = Registry("noise schedule", plugins="navlab.noise_schedules")


@dataclass(frozen=True)
class ConstantParams:
    factor: float = param(1.0, lo=0.01, hi=100.0, help="true σ / nominal σ")
    channels: tuple = param((), help=_CH_HELP, ui=False)


@SCHEDULES.register
class Constant(Schedule):
    key, label = "constant", "Constant"
    summary = "σ(t) = factor · σ_nominal (factor 1: the filters' R is right)."
    Params = ConstantParams

    def factor(self, u, k, m):
        return np.full_like(u, self.params.factor)


@dataclass(frozen=True)
class StepParams:
    at: float = param(0.5, lo=0.0, hi=1.0, help="when σ jumps, as a fraction of the run")
    factor: float = param(3.0, lo=0.01, hi=100.0, help="σ multiplier after the step")
    channels: tuple = param((), help=_CH_HELP, ui=False)


@SCHEDULES.register
class Step(Schedule):
    key, label = "step", "Step"
    summary = "σ jumps from nominal to factor·nominal at a chosen time."
    Params = StepParams

    def factor(self, u, k, m):
        return np.where(u >= self.params.at, self.params.factor, 1.0)


@dataclass(frozen=True)
class RampParams:
    start: float = param(0.25, lo=0.0, hi=1.0, help="ramp start, fraction of the run")
    stop: float = param(0.75, lo=0.0, hi=1.0, help="ramp end, fraction of the run")
    factor: float = param(3.0, lo=0.01, hi=100.0, help="σ multiplier reached at the end")
    channels: tuple = param((), help=_CH_HELP, ui=False)


@SCHEDULES.register
class Ramp(Schedule):
    key, label = "ramp", "Ramp"
    summary = "σ grows linearly from nominal to factor·nominal between two times."
    Params = RampParams

    def factor(self, u, k, m):
        p = self.params
        if p.stop <= p.start:
            raise NavlabError("noise schedule 'ramp': stop must be later than start")
        s = np.clip((u - p.start) / (p.stop - p.start), 0.0, 1.0)
        return 1.0 + (p.factor - 1.0) * s


@dataclass(frozen=True)
class SinusoidParams:
    amplitude: float = param(0.5, lo=0.0, hi=0.95, help="relative amplitude of σ's oscillation")
    periods: float = param(2.0, lo=0.1, hi=100.0, help="number of periods over the run")
    channels: tuple = param((), help=_CH_HELP, ui=False)


@SCHEDULES.register
class Sinusoid(Schedule):
    key, label = "sinusoid", "Sinusoid"
    summary = "σ(t) = σ_nominal · (1 + a·sin(2π·periods·t/T))."
    Params = SinusoidParams

    def factor(self, u, k, m):
        return 1.0 + self.params.amplitude * np.sin(2 * np.pi * self.params.periods * u)


@dataclass(frozen=True)
class HakfTanhParams:
    length: int = param(
        0, lo=0, hi=MAX_EPOCHS, help="the paper's len (epochs); 0 = this run's number of epochs"
    )
    channels: tuple = param((), help=_CH_HELP, ui=False)


@SCHEDULES.register
class HakfTanh(Schedule):
    """The time-varying noise of Zuo et al. 2017, eqs. 29–31 (ALGORITHMS.md §8.1, reading #1).

    The paper's σ in metres (nominal 10 m on every channel) is::

        r'_1 = 10 + 0.1 (1 + tanh(0.01 (k − len/4)))
        r'_2 = 30 + (0.01 + tanh(±0.01 (k − len/4 | len/2)))   (switch at k = 1.5 len/4)
        r'_3 = 40 + 2 (1 + tanh(−0.01 (k − len/2)))

    navlab applies the multipliers r'_i/10 to channel i (channel j of a scenario with m ≠ 3 uses
    curve j mod 3), so on the HAKF scenario (σ_nominal = 10 m) it is exactly the paper's σ.
    """

    key, label = "hakf-tanh", "HAKF tanh (Zuo 2017 eqs. 29–31)"
    summary = "The HAKF paper's smooth time-varying R: ≈1×, 3× and 4× nominal σ with tanh drifts."
    Params = HakfTanhParams

    def factor(self, u, k, m):
        L = float(self.params.length) or float(k[-1, 0])
        k = k[:, 0]
        r1 = 10 + 0.1 * (1 + np.tanh(0.01 * (k - L / 4)))
        r2 = np.where(
            k <= 1.5 * L / 4,
            30 + (0.01 + np.tanh(0.01 * (k - L / 4))),
            30 + (0.01 + np.tanh(-0.01 * (k - L / 2))),
        )
        r3 = 40 + 2 * (1 + np.tanh(-0.01 * (k - L / 2)))
        curves = np.stack([r1, r2, r3], axis=1) / 10.0
        return curves[:, [j % 3 for j in range(m)]]


@dataclass(frozen=True)
class BurstParams:
    start: float = param(0.25, lo=0.0, hi=1.0, help="burst centre-of-rise, fraction of the run")
    stop: float = param(0.75, lo=0.0, hi=1.0, help="burst centre-of-fall, fraction of the run")
    factor: float = param(10.0, lo=0.01, hi=1000.0, help="σ multiplier inside the burst")
    edge: float = param(0.025, lo=0.0, hi=0.5, help="tanh edge width, fraction of the run (0: sharp)")
    channels: tuple = param((), help=_CH_HELP, ui=False)


@SCHEDULES.register
class Burst(Schedule):
    """Interference burst: σ = σ0 (1 + (factor−1) b(t)), b = ½[tanh((u−start)/e) − tanh((u−stop)/e)].

    With start/stop 0.25/0.75, edge 0.025 and factor 10 on 200 s this is the VB-EKF scenario's
    interference (ALGORITHMS.md §8.4).
    """

    key, label = "burst", "Burst"
    summary = "A smooth (tanh-edged) burst of factor·σ on chosen channels between two times."
    Params = BurstParams

    def factor(self, u, k, m):
        p = self.params
        if p.stop <= p.start:
            raise NavlabError("noise schedule 'burst': stop must be later than start")
        if p.edge > 0:
            b = 0.5 * (np.tanh((u - p.start) / p.edge) - np.tanh((u - p.stop) / p.edge))
        else:
            b = ((u >= p.start) & (u <= p.stop)).astype(float)
        return 1.0 + (p.factor - 1.0) * b


def make_schedule(key: str, params: dict[str, Any] | None = None) -> Schedule:
    """Instantiate a registered noise schedule by key, validating its parameters."""
    return SCHEDULES.make(key, params)
