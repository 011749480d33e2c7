"""Outlier models: draw the measurement noise of a batch of runs, contamination included.

Each model returns, per run, epoch and channel, the noise actually added, the variance it was
drawn with (given to the oracle KF), the known additive mean (bias) and a mask of contaminated
entries (ground truth for detection rates). Magnitudes are in units of the channel's true σ at that
epoch, so a model fits every scenario; epochs are absolute indices 1 … K. The draws come from the
batch's measurement stream (:class:`navlab.scenarios.base.RunStream`: ``standard_normal``,
``random``, ``chisquare`` with per-run shapes, returning (B, *shape)), so run r's noise does not
depend on the other runs of the batch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple

import numpy as np

from navlab import params as P_
from navlab.errors import NavlabError
from navlab.linalg import Array
from navlab.noise import fisher as FI
from navlab.params import param
from navlab.registry import Registry

if TYPE_CHECKING:
    from navlab.scenarios.base import RunStream


class NoiseDraw(NamedTuple):
    """A batch's measurement noise, each (B, K+1, m)."""

    noise: Array
    var: Array
    bias: Array
    mask: Array


class OutlierModel:
    """Base class. ``draw(stream, std)`` with std (K+1, m) the true σ of the schedule."""

    key: ClassVar[str] = ""
    label: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    Params: ClassVar[type] = P_.NoParams

    def __init__(self, params: Any = None) -> None:
        if params is None or isinstance(params, dict):
            params = P_.build(self.Params, params, f"outlier model '{self.key}'")
        self.params = params

    def channel_mask(self, m: int) -> Array:
        chans = getattr(self.params, "channels", ())
        sel = np.zeros(m, dtype=bool)
        if not chans:
            sel[:] = True
            return sel
        bad = [c for c in chans if not 0 <= int(c) < m or int(c) != c]  # 0.5 was channel 0
        if bad:
            raise NavlabError(
                f"outlier model '{self.key}': channel(s) {bad} do not exist; "
                f"this scenario has channels 0 … {m - 1} (whole numbers)"
            )
        sel[[int(c) for c in chans]] = True
        return sel

    def draw(self, stream: RunStream, std: Array) -> NoiseDraw:
        """Noise of the batch's runs (each (B, K+1, m)) from its measurement stream."""
        raise NotImplementedError

    def fisher(self, std: Array) -> Array | None:
        """Fisher information (K+1, m) of each measurement entry about its mean, given the
        schedule's σ (K+1, m) (:mod:`navlab.noise.fisher`; the posterior Cramér–Rao bound's
        measurement term); None where the model does not state its density (no bound).
        """
        return None

    @staticmethod
    def _gaussian(stream: RunStream, std: Array) -> NoiseDraw:
        n = stream.standard_normal(std.shape)
        shape = n.shape
        return NoiseDraw(
            std * n, np.broadcast_to(std**2, shape), np.zeros(shape), np.zeros(shape, dtype=bool)
        )


#: Every outlier model, by key, in the order they are offered.
OUTLIERS: Registry[type[OutlierModel]] = Registry("outlier model", plugins="navlab.outlier_models")


@OUTLIERS.register
class NoOutliers(OutlierModel):
    key, label = "none", "No outliers"
    summary = "Gaussian noise with the schedule's σ only."

    def draw(self, stream, std):
        return self._gaussian(stream, std)

    def fisher(self, std):
        return 1.0 / np.asarray(std, dtype=float) ** 2


_CH = "contaminated channel indices (empty = all channels)"


@dataclass(frozen=True)
class MixtureParams:
    contamination: float = param(0.1, lo=0.0, hi=0.5, help="outlier ratio α (per channel, epoch)")
    scale: float = param(10.0, lo=1.0, hi=1000.0, help="outlier σ / nominal σ (κ)")
    channels: tuple = param((), help=_CH, ui=False)


@OUTLIERS.register
class Mixture(OutlierModel):
    """Gaussian mixture (1−α) N(0, σ²) + α N(0, (κσ)²) per channel and epoch (Zuo 2017, eq. 32)."""

    key, label = "mixture", "Gaussian mixture (contamination α)"
    summary = "Each entry is, with probability α, drawn with κ times the σ (HAKF eq. 32)."
    Params = MixtureParams

    def draw(self, stream, std):
        p = self.params
        n = stream.standard_normal(std.shape)
        hit = (stream.random(std.shape) < p.contamination) & self.channel_mask(std.shape[1])
        hit[:, 0] = False  # epoch 0 carries no measurement
        s = np.where(hit, p.scale * std, std)
        return NoiseDraw(s * n, s**2, np.zeros(n.shape), hit)

    def fisher(self, std):
        p = self.params
        std = np.asarray(std, dtype=float)
        ju = np.where(self.channel_mask(std.shape[1]), FI.mixture(p.contamination, p.scale), 1.0)
        return ju / std**2


@dataclass(frozen=True)
class IsolatedParams:
    start: int = param(20, lo=1, hi=10**7, help="first outlier epoch")
    stop: int = param(70, lo=1, hi=10**7, help="last outlier epoch (inclusive)")
    every: int = param(5, lo=1, hi=10**7, help="one outlier every this many epochs")
    mean: float = param(5.0, lo=-1000.0, hi=1000.0, help="outlier mean, in σ")
    scale: float = param(4.0, lo=0.0, hi=1000.0, help="outlier std added on top, in σ")
    channels: tuple = param((0,), help=_CH, ui=False)


@OUTLIERS.register
class Isolated(OutlierModel):
    """Isolated outliers N(mean, scale²) added every few epochs (Ge 2020, experiment 1).

    With σ = 2 m the defaults (mean 5σ, scale 4σ, epochs 20:5:70 on x) are the paper's N(10, 64).
    """

    key, label = "isolated", "Isolated periodic outliers"
    summary = "An outlier of mean μσ and std sσ every few epochs on chosen channels."
    Params = IsolatedParams

    def epochs(self, K: int) -> Array:
        p = self.params
        if p.stop < p.start:
            raise NavlabError(f"outlier model '{self.key}': stop must not be before start")
        return np.arange(p.start, min(p.stop, K) + 1, p.every)

    def draw(self, stream, std):
        p = self.params
        base = self._gaussian(stream, std)
        K = std.shape[0] - 1
        mask = np.zeros(std.shape, dtype=bool)  # the same epochs and channels in every run
        mask[np.ix_(self.epochs(K), np.flatnonzero(self.channel_mask(std.shape[1])))] = True
        extra = stream.standard_normal(std.shape)  # drawn for every entry: same stream layout
        bias = np.where(mask, p.mean * std, 0.0)
        noise = base.noise + np.where(mask, bias + p.scale * std * extra, 0.0)
        var = base.var + np.where(mask, (p.scale * std) ** 2, 0.0)
        B = len(stream)
        return NoiseDraw(
            noise, var, np.broadcast_to(bias, (B, *std.shape)), np.broadcast_to(mask, (B, *std.shape))
        )

    def fisher(self, std):
        # an outlier entry is N(μσ, (1 + s²)σ²) at known epochs: its mean is known (the
        # schedule is deterministic), its variance larger
        p = self.params
        std = np.asarray(std, dtype=float)
        K = std.shape[0] - 1
        var = std**2
        var[np.ix_(self.epochs(K), np.flatnonzero(self.channel_mask(std.shape[1])))] *= 1.0 + p.scale**2
        return 1.0 / var


@dataclass(frozen=True)
class ContinuousParams:
    start: int = param(50, lo=1, hi=10**7, help="first epoch of the burst")
    stop: int = param(70, lo=1, hi=10**7, help="last epoch of the burst (inclusive)")
    mean: float = param(0.0, lo=-1000.0, hi=1000.0, help="outlier mean, in σ")
    scale: float = param(4.0, lo=0.0, hi=1000.0, help="outlier std added on top, in σ")
    channels: tuple = param((0,), help=_CH, ui=False)


@OUTLIERS.register
class Continuous(Isolated):
    """A continuous run of outliers N(mean, scale²) (Ge 2020, experiment 2: epochs 50–70, var 64)."""

    key, label = "continuous", "Continuous outlier burst"
    summary = "Every epoch in a window carries an outlier of mean μσ and std sσ."
    Params = ContinuousParams

    def epochs(self, K: int) -> Array:
        p = self.params
        if p.stop < p.start:
            raise NavlabError(f"outlier model '{self.key}': stop must not be before start")
        return np.arange(p.start, min(p.stop, K) + 1)


@dataclass(frozen=True)
class StudentTParams:
    dof: float = param(3.0, lo=1.0, hi=1000.0, help="degrees of freedom ν (small = heavy tails)")
    mask_at: float = param(2.0, lo=1.0, hi=100.0, help="mark as outlier when drawn σ > this × σ")
    channels: tuple = param((), help=_CH, ui=False)


@OUTLIERS.register
class StudentT(OutlierModel):
    """Student-t noise σ·t_ν as a Gaussian scale mixture: v = σ n / sqrt(g/ν), g ~ χ²_ν.

    The drawn variance σ²ν/g is exact side information for the oracle; entries whose drawn σ
    exceeds ``mask_at``·σ are marked as outliers.
    """

    key, label = "student-t", "Student-t (heavy tails)"
    summary = "Heavy-tailed noise: Student-t with ν degrees of freedom and scale σ."
    Params = StudentTParams

    def draw(self, stream, std):
        p = self.params
        n = stream.standard_normal(std.shape)
        g = stream.chisquare(p.dof, std.shape)
        sel = self.channel_mask(std.shape[1])
        mult = np.where(sel, np.sqrt(p.dof / g), 1.0)
        mult[:, 0] = 1.0
        s = std * mult
        return NoiseDraw(s * n, s**2, np.zeros(n.shape), mult > p.mask_at)

    def fisher(self, std):
        p = self.params
        std = np.asarray(std, dtype=float)
        ju = np.where(self.channel_mask(std.shape[1]), FI.student_t(p.dof), 1.0)
        return ju / std**2


def make_outliers(key: str, params: dict[str, Any] | None = None) -> OutlierModel:
    """Instantiate a registered outlier model by key, validating its parameters."""
    return OUTLIERS.make(key, params)
