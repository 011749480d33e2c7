"""Comparing a filter's outputs against a pinned reference (the speed work's safety net)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

import numpy as np
import pytest

Cases = Callable[..., dict[str, np.ndarray]]
TOL = 1e-8  # relative: the fixed tolerance of the ``close`` quantities


class _OnFirstUse(Mapping):
    """``make()``'s dict, computed at the first lookup (never, if no lookup is needed)."""

    def __init__(self, make: Callable[[], dict[str, np.ndarray]]):
        self._make = make
        self._data: dict[str, np.ndarray] | None = None

    def _get(self) -> dict[str, np.ndarray]:
        if self._data is None:
            self._data = self._make()
        return self._data

    def __getitem__(self, key: str) -> np.ndarray:
        return self._get()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._get())

    def __len__(self) -> int:
        return len(self._get())


def pin_fixtures(all_cases: Cases, pin: Path):
    """Module-scoped fixtures ``current``, ``jittered`` (z perturbed at 1e-15 relative) and
    ``pinned`` for a test module whose ``all_cases(perturb)`` computes every pinned quantity.
    ``jittered`` is computed at its first lookup: only a quantity that misses the fixed 1e-8
    tolerance needs it (no linear filter's does, which halves test_linear_pinned's set-up)."""

    @pytest.fixture(scope="module")
    def current():
        return all_cases()

    @pytest.fixture(scope="module")
    def jittered():
        return _OnFirstUse(lambda: all_cases(1e-15))

    @pytest.fixture(scope="module")
    def pinned():
        with np.load(pin) as d:
            return dict(d)

    return current, jittered, pinned


def case_names(pin: Path) -> list[str]:
    """The pinned cases (keys are ``case/quantity``)."""
    return sorted({k.rsplit("/", 1)[0] for k in np.load(pin).files}) if pin.exists() else []


def regenerate(all_cases: Cases, pin: Path) -> None:
    """Overwrite the pinned reference (only with NAVLAB_REGEN_PIN=1: a deliberate act)."""
    if os.environ.get("NAVLAB_REGEN_PIN") != "1":
        raise SystemExit("set NAVLAB_REGEN_PIN=1 to overwrite the pinned reference")
    pin.parent.mkdir(exist_ok=True)
    np.savez_compressed(pin, **all_cases())
    print(f"wrote {pin} ({pin.stat().st_size} bytes)")


def rel_diff(a: np.ndarray, b: np.ndarray, q: str) -> float:
    """Largest difference of a from b relative to b's scale: x per state over time (x crosses
    zero), diag P elementwise, full P relative to √(P_ii P_jj)."""
    scale = np.maximum(np.abs(b), 1e-300)
    if q == "x":
        scale = np.maximum(np.nanmax(np.abs(b), axis=1, keepdims=True), 1e-300)
    if q == "P_end":
        d = np.sqrt(np.abs(np.diagonal(b, axis1=-2, axis2=-1)))
        scale = np.maximum(d[:, :, None] * d[:, None, :], 1e-300)
    ok = np.isfinite(b)
    return float(np.max(np.abs(a[ok] - b[ok]) / np.broadcast_to(scale, b.shape)[ok], initial=0.0))


def assert_matches_pin(
    case: str, current: dict, jittered: dict, pinned: dict, exact: tuple[str, ...], close: tuple[str, ...]
) -> None:
    """Decisions (``exact``) identical; the ``close`` quantities equal to 1e-8 relative, or to 100x
    the change that a 1e-15 relative perturbation of z causes in the current code where the case
    amplifies round-off more than that."""
    for q in exact:
        a, b = current[f"{case}/{q}"], pinned[f"{case}/{q}"]
        assert np.array_equal(a, b), f"{case}: {q} changed"
    for q in close:
        a, b = current[f"{case}/{q}"], pinned[f"{case}/{q}"]
        assert np.array_equal(np.isfinite(a), np.isfinite(b)), f"{case}: {q} finiteness changed"
        rel = rel_diff(a, b, q)
        if rel < TOL:  # within the fixed tolerance, whatever the round-off sensitivity
            continue
        sens = rel_diff(jittered[f"{case}/{q}"], a, q)
        tol = max(TOL, 100 * sens)
        assert rel < tol, f"{case}: {q} differs by {rel:.2e} relative (tolerance {tol:.1e})"
