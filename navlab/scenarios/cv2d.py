"""2-D constant-velocity target tracking (Ge, Zhang, Tang 2020, §4; ALGORITHMS.md §8.2).

State [x, V_x, y, V_y]; discrete white-noise acceleration model; positions measured with
σ_r = 2 m. The paper's two experiments are outlier presets on the x-position channel:
``isolated`` (every 5 epochs in 20–70, N(10, 64)) and ``continuous`` (epochs 50–70, N(0, 64)).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from navlab.filters.base import LinearModel
from navlab.noise import OutlierModel, Schedule
from navlab.params import MAX_EPOCHS, param
from navlab.scenarios.base import (
    MetricGroup,
    Scenario,
    ScenarioData,
    draw_measurement_noise,
    propagate,
    register_scenario,
    run_streams,
)


@dataclass(frozen=True)
class Cv2dParams:
    epochs: int = param(100, lo=2, hi=MAX_EPOCHS, help="number of epochs K (paper: not stated; 100)")
    dt: float = param(1.0, lo=1e-3, hi=100.0, help="sampling interval T (s)")
    sigma_q2: float = param(0.01, lo=0.0, hi=100.0, help="process-noise variance σ_q² (m²/s⁴)")
    sigma_r2: float = param(4.0, lo=1e-6, hi=1e6, help="nominal measurement variance σ_r² (m²)")
    p0_pos: float = param(4.0, lo=1e-9, hi=1e8, help="initial position variance (m²)")
    p0_vel: float = param(1.0, lo=1e-9, hi=1e8, help="initial velocity variance (m²/s²)")


def cv2d_matrices(dt: float, sigma_q2: float, sigma_r2: float):
    """F, Q = σ_q² Γ Γᵀ, H, R0 of the 2-D DWNA model (§8.2, correct reading of S1 eq. 8)."""
    F1 = np.array([[1.0, dt], [0.0, 1.0]])
    F = np.kron(np.eye(2), F1)
    G1 = np.array([[dt**2 / 2], [dt]])
    Gam = np.kron(np.eye(2), G1)
    Q = sigma_q2 * Gam @ Gam.T
    H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    R0 = sigma_r2 * np.eye(2)
    return F, Q, H, R0, Gam


X0 = np.array([1.25e5, -100.0, 1.25e5, -100.0])  # [m, m/s, m, m/s] (seed's "-100 m" is m/s)


@register_scenario
class Cv2d(Scenario):
    key = "cv2d"
    label = "2-D constant-velocity tracking"
    paper = "Ge, Zhang, Tang 2020 (IRAKF), §4"
    summary = (
        "A target moving at constant velocity with small random accelerations; x and y positions "
        "measured with σ = 2 m. The IRAKF paper's outlier experiments hit the x channel."
    )
    Params = Cv2dParams
    outlier_defaults: ClassVar[dict[str, dict[str, Any]]] = {
        "isolated": {"start": 20, "stop": 70, "every": 5, "mean": 5.0, "scale": 4.0, "channels": [0]},
        "continuous": {"start": 50, "stop": 70, "mean": 0.0, "scale": 4.0, "channels": [0]},
    }
    # what navlab is for, at first sight: the baseline, three filters that estimate R (Sage–Husa,
    # variational Bayes, and VB + Huber) and the oracle that is handed the true R(t)
    default_filters = ("kf", "sage-husa", "vb-akf", "hakf", "oracle-kf")
    pcrb = "linear"
    default_runs = 100
    headline = ("pos", "vel")

    def simulate(
        self, schedule: Schedule, outliers: OutlierModel, runs: Sequence[int], seed: int
    ) -> ScenarioData:
        p = self.params
        K = p.epochs
        F, Q, H, R0, Gam = cv2d_matrices(p.dt, p.sigma_q2, p.sigma_r2)
        P0 = np.diag([p.p0_pos, p.p0_vel, p.p0_pos, p.p0_vel])
        streams = run_streams(seed, runs)
        # truth: x_k = F x_{k-1} + Γ w_{k-1}, w ~ N(0, σ_q² I₂)
        w = streams.truth.standard_normal((K, 2)) * np.sqrt(p.sigma_q2)
        x = propagate(X0, F, w, Gam)
        x0 = X0 + streams.init.standard_normal(4) * np.sqrt(np.diag(P0))
        std = schedule.std(np.sqrt(np.diag(R0)), K)
        noise, var, bias, mask = draw_measurement_noise(streams, std, outliers)
        z = x @ H.T + noise
        z[:, 0] = np.nan
        window = np.arange(K + 1) >= 1
        return ScenarioData(
            scenario=self.key,
            t=np.arange(K + 1) * p.dt,
            model=LinearModel(F, Q, H, R0),
            x_true=x,
            z=z,
            R_true=var,
            R_schedule=std**2,
            outlier_mask=mask,
            bias=bias,
            x0=x0,
            P0=P0,
            runs=np.asarray(runs),
            state_names=("x", "V_x", "y", "V_y"),
            channel_names=("x", "y"),
            channel_units=("m", "m"),
            groups={
                "pos": MetricGroup((0, 2), "m", "position"),
                "vel": MetricGroup((1, 3), "m/s", "velocity"),
                "x_pos": MetricGroup((0,), "m", "x position"),
                "x_vel": MetricGroup((1,), "m/s", "x velocity"),
                "y_pos": MetricGroup((2,), "m", "y position"),
                "y_vel": MetricGroup((3,), "m/s", "y velocity"),
            },
            window=window,
        )
