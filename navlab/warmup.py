"""Compile (or load from numba's cache) every kernel navlab uses, before anyone waits for it.

The kernels live where they are used (:mod:`navlab.jit` is their bottom-layer mechanism); this
top-layer module exercises them through the code that uses them (the INS mechanisation, the
simulated truth, a tiny experiment of the filters with kernels). ``python -m navlab.warmup``
prints the seconds each took (the Docker image runs it at build time); ``python -m navlab.jit``
runs it too.
"""

from __future__ import annotations

import time

import numpy as np

from navlab import jit


def warm() -> dict[str, float]:
    """Compile (or load from the cache) every kernel navlab uses, on tiny inputs.

    Returns the seconds each took (empty without numba). ``python -m navlab.warmup`` prints them.
    """
    if not jit.enabled():
        return {}
    from navlab.ins import earth, strapdown
    from navlab.scenarios import base

    times = {}
    t0 = time.perf_counter()
    s = strapdown.init_state(0.7, -1.9, 1600.0, np.zeros(3), np.eye(3), B=2)
    t = np.array([0.0, 0.01, 0.02])
    strapdown.propagate_block(s, t, np.tile([0.0, 0.0, 9.8], (3, 1)), np.zeros((3, 3)), t_end_s=0.03)
    times["strapdown.propagate_block"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    e = np.zeros((1, 250, 15))  # long enough a recursion for the compiled path
    base.propagate(np.zeros(15), np.eye(15), e, np.eye(15), e)
    times["scenarios.base.propagate"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    earth.dcm_to_rotvec(earth.rotvec_to_dcm(np.zeros((2, 3))))
    times["earth rotation conversions"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    _warm_filters()
    times["filter kernels (solve, quadratic form, Joseph, VB, Sage–Husa, UKF steps, RBF clustering)"] = (
        time.perf_counter() - t0
    )
    t0 = time.perf_counter()
    _warm_ins_model()
    times["ins.lc model f, h, H"] = time.perf_counter() - t0
    return times


def _warm_filters() -> None:
    """The filter kernels, through the filters themselves (the signatures the runs use)."""
    from navlab.experiment import ExperimentSpec, run_experiment
    from navlab.filters import rbf

    filters = ("kf", "chi2-kf", "vb-akf", "hakf", "student-t-kf", "sage-husa", "irakf", "rakf", "rsshakf")
    # 12 epochs: past the 10-epoch residual window of IRAKF's R̂
    run_experiment(
        ExperimentSpec(scenario="gps-ins-rtk", filters=(*filters, "svd-ukf", "mfukf"), runs=2, epochs=12)
    )
    rbf.cluster_adaptive(np.zeros((3, 2)), 1.0, 1, 2)  # NNMFUKF's network trains at the window's end
    # the sigma-point steps (a linear model's UT is in closed form above): a nonlinear model
    run_experiment(ExperimentSpec(scenario="gps-ins-pseudorange", filters=("svd-ukf",), runs=2, epochs=3))


def _warm_ins_model() -> None:
    """The INS model's kernels on a still, level IMU block (the real model needs a recording)."""
    from navlab.ins import lc

    x, C, f_b = np.zeros((2, 15)), np.eye(3), np.tile([0.0, 0.0, 9.8], (3, 1))
    origin = np.array([0.7, -1.9, 1600.0, 6.4e6, 4.9e6])
    lc._F_RUNS.get()(x, np.empty((2, 15)), C, C, f_b, np.zeros((3, 3)), np.full(3, 0.01), origin)
    h, H = np.empty((2, 5)), np.empty((2, 5, 15))
    lc._HH_RUNS.get()(x, C, np.zeros(3), np.eye(3), np.ones(5), True, h, H)


if __name__ == "__main__":  # python -m navlab.warmup: compile (or load) every kernel, print the times
    import argparse

    doc = warm.__doc__.splitlines()[0]
    argparse.ArgumentParser(prog="python -m navlab.warmup", description=doc).parse_args()  # --help: no warm
    took = warm()
    if not took:
        print("numba not available (or NAVLAB_NUMBA=0): navlab uses its numpy paths")
    for name, sec in took.items():
        print(f"{name}: {sec:.2f} s")
