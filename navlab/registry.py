"""One registry mechanism for every kind of plug-in: filters, scenarios, noise schedules, outlier
models (and paper reproductions).

A :class:`Registry` maps a key (kebab-case, e.g. ``"huber-kf"``) to the registered object — a class
with a ``key`` attribute (filters, scenarios, schedules, outlier models) or any object with one (a
reproduction). It is a mapping (``reg[key]``, ``key in reg``, iteration in registration order), with

* :meth:`Registry.register` — the class decorator (or call) that adds an object;
* :meth:`Registry.lookup` — the object for a key, or a :class:`~navlab.errors.NavlabError` that
  names the known keys (what a user who mistyped one needs);
* :meth:`Registry.make` — ``lookup(key)(params)``: the instance with validated parameters.

A registry given a ``package`` imports that package and every module in it on first use, so a new
module dropped into the package is registered without touching any list, and the CLI, the app and
the contract tests all see it.

A registry given ``plugins`` (an entry-point group such as ``"navlab.filters"``) also loads, on
first use, every entry point of that group in the installed distributions: a user's own package
declares ``[project.entry-points."navlab.filters"] my-kf = "my_pkg.filter:MyKF"`` in its
pyproject.toml and, once pip-installed, its filter is in the registry (CLI, pages, contract tests)
with no change to navlab. An entry point may name the object (registered if its module did not
already register it with the decorator) or a module (whose import registers its objects). A plugin
that fails to load does not take navlab down: the failure is logged, kept in
:attr:`Registry.plugin_errors` and named by :meth:`Registry.lookup` when its key is asked for.
"""

from __future__ import annotations

import functools
import importlib
import importlib.metadata
import logging
import pkgutil
import threading
import types
from collections.abc import Callable, Iterator, MutableMapping
from typing import Any, Generic, TypeVar

from navlab.errors import NavlabError

T = TypeVar("T")

log = logging.getLogger(__name__)


@functools.cache
def installed_entry_points() -> importlib.metadata.EntryPoints:
    """Every entry point of the installed distributions, read once per process (one scan of the
    distributions' metadata, ~15 ms, instead of one per registry).
    """
    return importlib.metadata.entry_points()


class Registry(MutableMapping[str, T], Generic[T]):
    """Key → registered object, in registration order.

    Parameters
    ----------
    kind : what is registered, singular ("filter", "noise schedule"): used in messages.
    package : dotted name of a package whose modules register into this registry; they are
        imported (once) before the registry is first read.
    check : called with each object before it is added; raises to refuse it.
    plugins : entry-point group (``"navlab.filters"``) whose entry points in the installed
        distributions are loaded before the registry is first read.
    """

    def __init__(
        self,
        kind: str,
        *,
        package: str | None = None,
        check: Callable[[T], None] | None = None,
        plugins: str | None = None,
    ) -> None:
        self.kind = kind
        self.package = package
        self.check = check
        self.plugins = plugins
        #: entry-point name → why that plugin could not be loaded (one line)
        self.plugin_errors: dict[str, str] = {}
        #: registry key → the distribution ("name version") that provided it, for plugins
        self.plugin_sources: dict[str, str] = {}
        self._items: dict[str, T] = {}
        self._loaded = package is None and plugins is None
        self._lock = threading.Lock()

    # -- adding ---------------------------------------------------------------------------
    def register(self, obj: T) -> T:
        """Add ``obj`` under ``obj.key`` (usable as a class decorator); returns ``obj``.

        The key must be non-empty kebab-case; a second, different object under the same key is
        refused (re-registering the same object is a no-op).
        """
        key = getattr(obj, "key", None)
        if not isinstance(key, str) or not key or key != key.lower() or " " in key or "_" in key:
            raise ValueError(f"{self.kind} key must be kebab-case, got {key!r}")
        if self.check is not None:
            self.check(obj)
        with self._lock:
            if key in self._items and self._items[key] is not obj:
                raise ValueError(f"{self.kind} key {key!r} registered twice")
            self._items[key] = obj
        return obj

    # -- reading --------------------------------------------------------------------------
    def _load(self) -> None:
        # no lock around the imports (a module importing under another thread's lock could
        # deadlock); two threads loading at once is harmless: imports are idempotent and
        # re-registering the same class is a no-op
        if self._loaded:
            return
        if self.package is not None:
            pkg = importlib.import_module(self.package)
            for info in pkgutil.iter_modules(getattr(pkg, "__path__", [])):
                importlib.import_module(f"{self.package}.{info.name}")
        self._loaded = True  # before the plugins: a plugin module may read this registry
        if self.plugins is not None:
            for ep in installed_entry_points().select(group=self.plugins):
                self._load_plugin(ep)

    def _load_plugin(self, ep: importlib.metadata.EntryPoint) -> None:
        """Load one entry point; a failure is logged and kept, never raised."""
        dist = f"{ep.dist.name} {ep.dist.version}" if ep.dist is not None else "?"
        before = set(self._items)
        try:
            obj = ep.load()
            if getattr(obj, "key", None) is not None and not isinstance(obj, types.ModuleType):
                self.register(obj)
        except Exception as exc:  # a user's package: say which and why, keep navlab usable
            why = f"{type(exc).__name__}: {exc}"
            self.plugin_errors[ep.name] = f"{ep.value} (from {dist}): {why}"
            log.warning("%s plugin %r (%s, from %s) not loaded: %s", self.kind, ep.name, ep.value, dist, why)
            return
        for key in set(self._items) - before:
            self.plugin_sources[key] = dist

    def lookup(self, key: str) -> T:
        """The object registered as ``key``; NavlabError naming the known keys otherwise."""
        self._load()
        try:
            return self._items[key]
        except (KeyError, TypeError):
            known = ", ".join(sorted(self._items)) or "(none)"
            broken = self.plugin_errors.get(key) if isinstance(key, str) else None
            if broken is not None:
                raise NavlabError(f"the {self.kind} plugin '{key}' failed to load: {broken}") from None
            raise NavlabError(f"unknown {self.kind} '{key}'; known: {known}") from None

    def make(self, key: str, params: dict[str, Any] | None = None) -> Any:
        """``lookup(key)(params)``: an instance with validated parameters."""
        return self.lookup(key)(params or {})

    def __getitem__(self, key: str) -> T:
        self._load()
        return self._items[key]

    def __setitem__(self, key: str, obj: T) -> None:
        if getattr(obj, "key", key) != key:
            raise ValueError(f"{self.kind} {obj!r} has key {obj.key!r}, not {key!r}")
        self.register(obj)

    def __delitem__(self, key: str) -> None:
        with self._lock:
            del self._items[key]

    def __iter__(self) -> Iterator[str]:
        self._load()
        return iter(list(self._items))

    def __len__(self) -> int:
        self._load()
        return len(self._items)

    def __contains__(self, key: object) -> bool:
        self._load()
        return key in self._items

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}, {list(self._items)})"
