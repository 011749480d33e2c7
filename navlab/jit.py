"""Optional compiled kernels: numba where it is installed and imports, numpy everywhere else.

A few loops of navlab are pure Python-call overhead when batched with numpy over a handful of
runs (the strapdown mechanisation: ≈ 50 µs per batched IMU sample whatever the batch; the INS
model's f, h, H; the small solves, quadratic forms, Joseph form, VB iterations and the Sage–Husa
clamp's test of the filters, where numpy needs several calls per epoch) or must
add numbers in one fixed order per run (the simulated truth: the same bits for run r alone or in
a batch). For those, navlab keeps two paths:

* the numpy path, batched over the runs: the reference, always available;
* a kernel written for ONE run in textbook form (plain loops over the equations), compiled by
  numba (``nopython``, no ``fastmath``, so IEEE arithmetic in source order) and looped over the
  runs. The tests compare the two paths (to round-off: tests/unit/test_jit.py,
  tests/unit/test_jit_kernels.py).

The compiled path is used when numba imports; ``NAVLAB_NUMBA=0`` (or numba missing or broken)
selects the numpy paths. Compiled kernels are cached on disk (numba's ``cache=True``: next to the
sources, or in ``NUMBA_CACHE_DIR`` where the code folder is read-only, as in the Docker image).
The first compile of every kernel costs a few seconds once per machine; :func:`navlab.warmup.warm`
pays it up front (the Docker image runs it at build time, so the app's first click does not).
"""

from __future__ import annotations

import contextlib
import os
import threading
import types
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

__all__ = ["Kernel", "carray", "enabled", "numpy_paths"]


_OFF = os.environ.get("NAVLAB_NUMBA", "").strip().lower() in ("0", "off", "false", "no")
_numba: Any = None
_tried = False
_lock = threading.Lock()
_force_numpy = False


def _load_numba() -> Any:
    """numba, imported on first use (≈ 0.5 s: a process that never runs a kernel never pays it).

    None when disabled, missing or broken (e.g. llvmlite built for another numpy).
    """
    global _numba, _tried
    with _lock:  # Streamlit sessions are threads
        if not _tried:
            if not _OFF:
                try:
                    import numba
                except Exception:
                    numba = None
                _numba = numba
            _tried = True
    return _numba


def enabled() -> bool:
    """True when compiled kernels are used (numba imports and ``NAVLAB_NUMBA`` is not 0)."""
    return _load_numba() is not None


class Kernel:
    """A function written for numba, compiled on first use (nopython, cached on disk).

    ``kernel.get()`` returns the compiled dispatcher, or None without numba (or with
    ``NAVLAB_NUMBA=0``): the caller then runs its numpy path. The function must be plain
    numba-compatible Python over scalars and numpy arrays.

    ``uses``: the kernels this one calls (by their function's name, as plain Python would), e.g.
    a one-run mechanisation step shared by two loops. They are compiled first and the calls are
    bound to their compiled versions (the Python functions themselves stay plain).
    """

    def __init__(self, fn: Callable, uses: tuple[Kernel, ...] = ()) -> None:
        self.fn = fn
        self.uses = uses
        self._dispatcher: Any = None

    def get(self) -> Callable | None:
        """The compiled kernel, or None (use the numpy path)."""
        if _force_numpy:
            return None
        if self._dispatcher is None:
            numba = _load_numba()
            if numba is None:
                return None
            fn = self.fn
            if self.uses:  # the same function with its callees bound to their compiled versions
                env = dict(fn.__globals__)
                env.update({k.fn.__name__: k.get() for k in self.uses})
                fn = types.FunctionType(fn.__code__, env, fn.__name__, fn.__defaults__, fn.__closure__)
                fn.__qualname__, fn.__module__, fn.__doc__ = (
                    self.fn.__qualname__,
                    self.fn.__module__,
                    self.fn.__doc__,
                )
            self._dispatcher = numba.njit(cache=True, nogil=True)(fn)
        return self._dispatcher


def carray(a: Any) -> np.ndarray:
    """``a`` as a C-contiguous, writeable float64 array, copied only if needed.

    Keeps one compiled signature per kernel: a read-only or strided argument would compile
    another (seconds).
    """
    if type(a) is np.ndarray and a.dtype == _F8:
        flags = a.flags
        if flags.c_contiguous and flags.writeable:
            return a  # the usual case: no call of np.require (≈ 3 µs)
    return np.require(a, dtype=np.float64, requirements=["C", "W"])


_F8 = np.dtype(np.float64)


@contextlib.contextmanager
def numpy_paths() -> Iterator[None]:
    """Within the block every kernel runs its numpy path (tests and benchmarks compare them).

    Process-wide (not per thread): for tests and benchmarks, not for concurrent app sessions.
    """
    global _force_numpy
    before, _force_numpy = _force_numpy, True
    try:
        yield
    finally:
        _force_numpy = before


if __name__ == "__main__":  # python -m navlab.jit: kept as a name for python -m navlab.warmup
    import runpy  # by name, not an import: the kernels' layer knows nothing of what they serve

    runpy.run_module("navlab.warmup", run_name="__main__", alter_sys=True)
