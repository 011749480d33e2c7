"""Fisher information of a measurement's location under each noise density (unit scale).

For noise v = σ·u with u of density p (symmetric, unit scale), the information a measurement
z = h(x) + v carries about h(x) is J = J_u / σ², with J_u = ∫ p'(u)² / p(u) du (the Fisher
information of location). It enters the posterior Cramér–Rao bound (:mod:`navlab.pcrb`) as the
measurement term H' diag(J) H. Gaussian: J_u = 1 (the bound is then the Kalman filter's own
covariance). Of all densities of a given variance the Gaussian carries the LEAST information
(J_u ≥ 1 / Var u, equality for the Gaussian alone): heavy-tailed noise holds more than a filter
that treats it as Gaussian of its variance can use, and the bound says how much more.

* Student-t with ν degrees of freedom: closed form J_u = (ν + 1) / (ν + 3).
* Contaminated Gaussian (1 − α) N(0, 1) + α N(0, κ²): no closed form; by adaptive quadrature
  (:func:`scipy.integrate.quad`) of p·score², the score −u·(w + (1 − w)/κ²) with w the posterior
  weight of the nominal component, computed in log space (no underflow in the far tails).
"""

from __future__ import annotations

import functools
import itertools
import math

import numpy as np

from navlab.errors import NavlabError

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


def student_t(dof: float) -> float:
    """J_u of a unit-scale Student-t with ``dof`` degrees of freedom: (ν + 1) / (ν + 3)."""
    if not dof > 0:
        raise NavlabError(f"Student-t degrees of freedom must be > 0, got {dof!r}")
    return (dof + 1.0) / (dof + 3.0)


def mixture_density(u: np.ndarray, alpha: float, kappa: float) -> tuple[np.ndarray, np.ndarray]:
    """(p(u), score d log p / du) of (1 − α) N(0, 1) + α N(0, κ²), stable in the tails."""
    u = np.asarray(u, dtype=float)
    la = np.log1p(-alpha) - 0.5 * u * u - _LOG_SQRT_2PI if alpha < 1 else np.full(u.shape, -np.inf)
    lb = (
        math.log(alpha) - math.log(kappa) - 0.5 * (u / kappa) ** 2 - _LOG_SQRT_2PI
        if alpha > 0
        else np.full(u.shape, -np.inf)
    )
    lp = np.logaddexp(la, lb)
    w = np.exp(la - lp)  # posterior weight of the nominal component
    score = -u * (w + (1.0 - w) / kappa**2)
    return np.exp(lp), score


@functools.lru_cache(maxsize=256)
def mixture(alpha: float, kappa: float) -> float:
    """J_u of the contaminated Gaussian (1 − α) N(0, 1) + α N(0, κ²), by quadrature.

    The integrand p·score² is even: twice the integral over [0, ∞), split where its mass lies
    (the nominal core, the outliers' scale κ, the tail) so the adaptive rule sees every part.
    """
    alpha, kappa = float(alpha), float(kappa)
    if not 0.0 <= alpha <= 1.0:
        raise NavlabError(f"contamination α must lie in [0, 1], got {alpha!r}")
    if not kappa > 0:
        raise NavlabError(f"outlier scale κ must be > 0, got {kappa!r}")
    if alpha == 0.0:
        return 1.0
    if alpha == 1.0:
        return 1.0 / kappa**2

    def f(u: float) -> float:
        p, s = mixture_density(np.array([u]), alpha, kappa)
        return float(p[0] * s[0] ** 2)

    from scipy import integrate  # here: scipy.integrate slows every process's start

    top = max(1.0, kappa)
    edges = [0.0, 1.0, 3.0, 8.0, *(c * top for c in (1.0, 3.0, 8.0, 40.0) if c * top > 8.0)]
    edges = sorted(set(edges))
    total = 0.0
    for a, b in itertools.pairwise(edges):
        total += integrate.quad(f, a, b, epsabs=1e-13, epsrel=1e-11, limit=200)[0]
    total += integrate.quad(f, edges[-1], np.inf, epsabs=1e-14, limit=200)[0]
    return 2.0 * total
