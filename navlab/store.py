"""The results store: finished Monte Carlo tasks on disk, keyed by a hash of their configuration.

Every task of a sweep or a tuning (:mod:`navlab.tasks`: one filter's configuration × a block of
runs) is stored when it finishes, under the SHA-256 of its full configuration, the navlab
version and the code itself (:func:`code_id`: a changed filter, scenario or metric never gets an
older result back, even between two commits of one version), so

* an interrupted sweep or tuning resumes where it stopped (the finished tasks are found),
* a repeated one returns at once (every task is found),
* concurrent sessions (two shells, the app's sessions, several app servers on one disk) share it
  safely: a file is written under a temporary name in the same folder and renamed into place
  (``os.replace`` is atomic), so a reader sees a whole file or none; two writers of one key
  write the same content; an entry that cannot be read (a file cut short, a folder in its place,
  arrays of the wrong length: :func:`navlab.tasks.compute` checks them) is removed and recomputed,
* its size is bounded: above ``max_bytes`` the least recently used files go first (a hit
  refreshes a file's time), checked after every write.

Entries are ``.npz`` files of plain arrays and one JSON header (``numpy.load`` with
``allow_pickle=False``: a store file is never executable). Location: ``NAVLAB_STORE`` or
``--store DIR``, default ``$XDG_CACHE_HOME/navlab/store`` (``~/.cache/navlab/store``); size
``NAVLAB_STORE_MAX`` (e.g. ``2GB``, default 2 GB). ``NAVLAB_STORE=off`` disables it.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import shutil
import tempfile
import threading
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from navlab import __version__
from navlab.errors import NavlabError
from navlab.memory import fmt_bytes, parse_bytes

ENV_DIR = "NAVLAB_STORE"
ENV_MAX = "NAVLAB_STORE_MAX"
DEFAULT_MAX = 2 * 2**30
SUFFIX = ".npz"


def default_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "navlab" / "store"


@functools.cache
def code_id() -> str:
    """SHA-256 (hex) of the navlab package's Python sources (their paths and contents)."""
    h = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for f in sorted(root.rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def key_of(config: Any) -> str:
    """SHA-256 (hex) of a JSON-serialisable configuration, the navlab version and its code."""
    text = json.dumps(
        {"config": config, "navlab": __version__, "code": code_id()}, sort_keys=True, separators=(",", ":")
    )
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


class Store:
    """A folder of finished tasks (module note). ``root=None``: no store (nothing kept)."""

    def __init__(self, root: str | Path | None, max_bytes: int = DEFAULT_MAX) -> None:
        self.root = None if root is None else Path(root)
        self.max_bytes = int(max_bytes)
        self._lock = threading.Lock()
        if self.root is not None:
            try:
                self.root.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                why = "a file, not a folder" if self.root.is_file() else exc.strerror
                raise NavlabError(
                    f"cannot create the results store {self.root}: {why}; choose another "
                    f"folder with --store DIR or {ENV_DIR}=DIR ({ENV_DIR}=off: no store)"
                ) from None

    @classmethod
    def open(cls, root: str | Path | None = None, max_bytes: int | str | None = None) -> Store:
        """The store at ``root`` (else ``NAVLAB_STORE``, else the default folder; ``off``: none)."""
        where = root if root is not None else os.environ.get(ENV_DIR) or default_dir()
        if str(where).strip().lower() in ("off", "none", ""):
            return cls(None)
        size = max_bytes if max_bytes is not None else os.environ.get(ENV_MAX) or DEFAULT_MAX
        if isinstance(size, str):
            size = parse_bytes(
                size,
                f"{ENV_MAX}, the results store's size limit,",
                f"; give a size such as 2GB ({ENV_DIR}=off keeps no results)",
            )
        return cls(Path(where).expanduser(), int(size))

    def __repr__(self) -> str:
        return f"Store({self.root}, max {fmt_bytes(self.max_bytes)})"

    def path(self, key: str) -> Path:
        assert self.root is not None
        return self.root / key[:2] / f"{key}{SUFFIX}"

    # ------------------------------------------------------------------------- entries

    def get(self, key: str) -> tuple[dict[str, Any], dict[str, np.ndarray]] | None:
        """(header, arrays) stored under ``key``, or None (missing or unreadable)."""
        if self.root is None:
            return None
        p = self.path(key)
        try:
            with np.load(p, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            header = json.loads(str(arrays.pop("__header__")))
        except FileNotFoundError:
            return None
        except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError):
            # a file cut short (disk full, a crash before the rename cannot leave one), written
            # by something else, or a folder in its place: recompute it
            self.discard(key)
            return None
        if not isinstance(header, dict) or header.get("key") != key:
            self.discard(key)
            return None
        with contextlib.suppress(OSError):
            os.utime(p)  # least recently used goes first
        return header, arrays

    def discard(self, key: str) -> None:
        """Remove the entry ``key`` whatever its form (a damaged file, a folder in its place), so
        that it is recomputed; one that cannot be removed is left for :meth:`put` to report.
        """
        if self.root is None:
            return
        p = self.path(key)
        with contextlib.suppress(OSError):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink(missing_ok=True)

    def __contains__(self, key: str) -> bool:
        return self.root is not None and self.path(key).exists()

    def put(self, key: str, header: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        """Store ``arrays`` (names → numpy arrays) and ``header`` (JSON) under ``key``, atomically."""
        if self.root is None:
            return
        p = self.path(key)
        head = json.dumps({**header, "key": key, "navlab": __version__}, sort_keys=True)
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=SUFFIX, dir=p.parent)
            try:
                with os.fdopen(fd, "wb") as f:
                    np.savez(f, __header__=np.array(head), **arrays)
                os.replace(tmp, p)
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
        except OSError as exc:
            raise NavlabError(
                f"cannot write to the results store {self.root}: {exc.strerror}; free some space, "
                f"or choose another folder with --store DIR / {ENV_DIR}=DIR"
            ) from None
        self.prune()

    # ------------------------------------------------------------------------- size

    def files(self) -> list[tuple[float, int, Path]]:
        """(modification time, bytes, path) of every entry."""
        if self.root is None:
            return []
        out = []
        for p in self.root.glob(f"??/*{SUFFIX}"):
            if p.name.startswith(".tmp-"):
                continue
            try:
                s = p.stat()
            except FileNotFoundError:  # removed by another session meanwhile
                continue
            out.append((s.st_mtime, s.st_size, p))
        return out

    def size(self) -> int:
        return sum(b for _, b, _ in self.files())

    def prune(self, max_bytes: int | None = None) -> int:
        """Remove the least recently used entries until the store holds at most ``max_bytes``;
        returns the number removed.
        """
        limit = self.max_bytes if max_bytes is None else int(max_bytes)
        with self._lock:
            entries = sorted(self.files())
            total = sum(b for _, b, _ in entries)
            removed = 0
            for _, b, p in entries:
                if total <= limit:
                    break
                p.unlink(missing_ok=True)
                total -= b
                removed += 1
            return removed

    def clear(self) -> None:
        self.prune(0)
