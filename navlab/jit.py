"""Optional compiled kernels: numba where it is installed and imports, numpy everywhere else.

A few loops of navlab are pure Python-call overhead when batched with numpy over a handful of
runs (the strapdown mechanisation: the same cost per batched IMU sample whatever the batch; the INS
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

__all__ = ["Kernel", "RunStep", "carray", "enabled", "numpy_paths"]


_SETTING = os.environ.get("NAVLAB_NUMBA", "").strip().lower()
_OFF = _SETTING in ("0", "off", "false", "no")
if _SETTING not in ("", "1", "on", "true", "yes") and not _OFF:
    import warnings

    warnings.warn(
        f"NAVLAB_NUMBA={_SETTING!r} is neither 0/off nor 1/on: the compiled kernels stay on", stacklevel=1
    )
_numba: Any = None
_tried = False
_lock = threading.Lock()
_force_numpy = False


def _load_numba() -> Any:
    """numba, imported on first use (a process that never runs a kernel never pays its import).

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


class RunStep:
    """A step written for ONE run, looped over the Monte Carlo runs: the filters' one implementation.

    ``fn(*one_run, *params) -> tuple`` is plain numba-compatible Python, one equation a line as
    the paper prints it. ``step(runs, params)`` calls it for r = 0 … B−1 with ``a[r]`` of every
    array of ``runs`` (leading axis B) and ``params`` shared by the runs, and returns its results
    stacked over the runs. ``outs`` declares them: per result, the index of the run argument
    whose one-run shape it has (None: a scalar; or a function of the run arguments' one-run
    shapes that returns its shape, e.g. ``lambda x, P: (2 * x[0] + 1, x[0])``) and its dtype.
    With numba the loop and ``fn``
    are compiled together (``fn``'s helpers in ``uses``, as for :class:`Kernel`); without it, or
    within :func:`numpy_paths`, the same loop runs the same Python uncompiled: the fallback and
    the tests' oracle.
    """

    def __init__(
        self,
        fn: Callable,
        n_runs: int,
        outs: tuple[tuple[int | Callable[..., tuple[int, ...]] | None, type], ...],
        uses: tuple[Kernel, ...] = (),
    ) -> None:
        self.step = Kernel(fn, uses)
        self.fn, self.n_runs, self.outs = fn, n_runs, outs
        self._loop: Any = None

    def __call__(self, runs: tuple, params: tuple) -> list[np.ndarray]:
        if len(runs) != self.n_runs:
            raise TypeError(f"{self.fn.__name__} takes {self.n_runs} arrays over the runs")
        runs = [_contiguous(a) for a in runs]
        params = tuple(_param(v) for v in params)
        B = runs[0].shape[0]
        outs = [np.empty((B, *_one_run_shape(i, runs)), dt) for i, dt in self.outs]
        loop = self._compiled(len(params))
        if loop is not None:
            loop(*runs, *params, *outs)
            return outs
        for r in range(B):  # the same loop, uncompiled
            for out, value in zip(outs, self.fn(*[a[r] for a in runs], *params), strict=True):
                out[r] = value
        return outs

    def get(self) -> Callable | None:
        """The compiled loop over runs, once a call has compiled it (None before, or without numba)."""
        return self._loop

    def _compiled(self, n_params: int) -> Callable | None:
        step = self.step.get()
        if step is None:
            return None
        if self._loop is None:
            code, todo = [self.fn], list(self.step.uses)
            while todo:  # the step's helpers and theirs: a change in any of them is a new loop
                kernel = todo.pop()
                code.append(kernel.fn)
                todo.extend(kernel.uses)
            self._loop = _runs_loop(self.fn.__name__, code, step, self.n_runs, n_params, len(self.outs))
        return self._loop


def _one_run_shape(spec: Any, runs: list[np.ndarray]) -> tuple[int, ...]:
    """The one-run shape of a result declared by ``spec`` (see :class:`RunStep`)."""
    if spec is None:
        return ()
    if callable(spec):
        return tuple(spec(*[a.shape[1:] for a in runs]))
    return runs[spec].shape[1:]


def _runs_loop(
    name: str, code: list[Callable], step: Callable, n_runs: int, n_params: int, n_outs: int
) -> Callable:
    """The compiled loop over runs around ``step``, generated for its arity.

    Cached on disk under a name that changes with the code of the step and its helpers (numba's
    cache would not see a change of a function called from another file).
    """
    import hashlib

    a = [f"a{i}" for i in range(n_runs)]
    p = [f"p{i}" for i in range(n_params)]
    o = [f"o{i}" for i in range(n_outs)]
    text = b"".join(f.__code__.co_code + repr(f.__code__.co_consts).encode() for f in code)
    name = f"_runs_{name}_{hashlib.sha1(text).hexdigest()[:10]}"
    call = ", ".join([f"{x}[r]" for x in a] + p)
    body = "".join(f"        {x}[r] = res[{i}]\n" for i, x in enumerate(o))
    head = f"def {name}({', '.join(a + p + o)}):\n    for r in range({a[0]}.shape[0]):\n"
    src = f"{head}        res = step({call})\n{body}"
    env = {"step": step, "np": np}
    exec(compile(src, __file__, "exec"), env)
    loop = env[name]
    loop.__module__ = __name__
    return _load_numba().njit(cache=True, nogil=True)(loop)


def _contiguous(a: Any) -> np.ndarray:
    """``a`` C-contiguous and writeable with its own dtype (floats as float64: one signature)."""
    if type(a) is np.ndarray and a.dtype.char in "d?":
        flags = a.flags
        if flags.c_contiguous and flags.writeable:
            return a  # the usual case: as it is
    a = np.asarray(a)
    return carray(a) if a.dtype.kind in "fiu" else np.require(a, requirements=["C", "W"])


def _param(v: Any) -> Any:
    """A shared parameter in one canonical type (Python scalars, C-contiguous writeable arrays).

    A read-only or strided array or a numpy scalar would compile another loop (seconds).
    """
    if isinstance(v, bool | np.bool_):
        return bool(v)
    if isinstance(v, int | np.integer):
        return int(v)
    if isinstance(v, float | np.floating):
        return float(v)
    return _contiguous(v)


def carray(a: Any) -> np.ndarray:
    """``a`` as a C-contiguous, writeable float64 array, copied only if needed.

    Keeps one compiled signature per kernel: a read-only or strided argument would compile
    another (seconds).
    """
    if type(a) is np.ndarray and a.dtype == _F8:
        flags = a.flags
        if flags.c_contiguous and flags.writeable:
            return a  # the usual case: no call of np.require
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
