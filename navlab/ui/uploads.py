"""Uploaded files live as long as the browser session, then are removed.

Each session that uploads a recording gets ONE temporary folder (``navlab-upload-*`` in the
system's temp directory), owned by a :class:`SessionUploads` object kept in the session's state.
The folder is removed

* when the session ends: Streamlit drops the session's state (``server.disconnectedSessionTTL``,
  120 s after the browser tab closes), the owner object is freed and its finalizer removes the
  folder (also when the server shuts down normally);
* at the latest :data:`MAX_IDLE_S` after the session last used it: :func:`sweep` (run on every
  upload and every visit of the Real data page) removes any navlab upload folder untouched for
  that long, so a server that was killed, or a session that was never closed, leaves nothing
  behind for long;
* for a broken upload, at once (only its error message is kept).

A session keeps only its current upload: uploading other files replaces the previous ones.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import time
import weakref
from pathlib import Path

#: Prefix of every upload folder navlab creates in the temp directory.
PREFIX = "navlab-upload-"
#: A navlab upload folder untouched for this long is removed by :func:`sweep` (s).
MAX_IDLE_S = 3600.0
SESSION_KEY = "_navlab_uploads"


def _remove(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)


def upload_root() -> Path:
    """Where upload folders are created: the system's temp directory (``TMPDIR``)."""
    return Path(tempfile.gettempdir())


class SessionUploads:
    """The upload folder of one session; removed when this object is freed (session end).

    Parameters
    ----------
    root : directory to create the folder in (default :func:`upload_root`).
    """

    def __init__(self, root: Path | None = None) -> None:
        self.root = Path(root) if root is not None else upload_root()
        self.path = Path(tempfile.mkdtemp(prefix=PREFIX, dir=self.root))
        self._finalizer = weakref.finalize(self, _remove, self.path)

    def folder(self, *contents: bytes | None) -> Path:
        """An empty-or-reused sub-folder for one upload (named by a hash of its files).

        Other uploads of this session are removed: the session keeps only its current one.
        """
        h = hashlib.sha256(b"\0".join(c or b"" for c in contents)).hexdigest()[:16]
        d = self.path / h
        self.path.mkdir(parents=True, exist_ok=True)  # a sweep may have removed an idle session's folder
        for other in self.path.iterdir():
            if other.name != h:
                _remove(other) if other.is_dir() else other.unlink(missing_ok=True)
        d.mkdir(exist_ok=True)
        self.touch()
        return d

    def touch(self) -> None:
        """Mark the folder as in use now (the idle sweep measures from here)."""
        now = time.time()
        try:
            os.utime(self.path, (now, now))
            for p in self.path.iterdir():
                os.utime(p, (now, now))
        except OSError:
            pass

    def folders(self) -> list[Path]:
        """Upload folders of this session (what a configuration loaded in it may name)."""
        return [self.path]

    def remove(self) -> None:
        """Remove the folder now (also done automatically when the session ends)."""
        self._finalizer()

    @property
    def alive(self) -> bool:
        return self._finalizer.alive


def sweep(root: Path | None = None, max_idle_s: float = MAX_IDLE_S, now: float | None = None) -> int:
    """Remove navlab upload folders untouched for more than ``max_idle_s``; returns how many."""
    root = Path(root) if root is not None else upload_root()
    now = time.time() if now is None else now
    n = 0
    try:
        candidates = list(root.glob(PREFIX + "*"))
    except OSError:
        return 0
    for p in candidates:
        try:
            newest = max([p.stat().st_mtime, *(c.stat().st_mtime for c in p.iterdir())])
        except OSError:
            continue
        if now - newest > max_idle_s and p.is_dir():
            _remove(p)
            n += 1
    return n


def session_uploads() -> SessionUploads:
    """The :class:`SessionUploads` of the current browser session (created on first use)."""
    import streamlit as st

    up = st.session_state.get(SESSION_KEY)
    if up is None or not isinstance(up, SessionUploads) or not up.alive:
        up = SessionUploads()
        st.session_state[SESSION_KEY] = up
    return up


def offered_folders() -> list[Path]:
    """Upload folders of this session (empty when it uploaded nothing); no folder is created."""
    import streamlit as st

    up = st.session_state.get(SESSION_KEY)
    return up.folders() if isinstance(up, SessionUploads) and up.alive else []


__all__ = [
    "MAX_IDLE_S",
    "PREFIX",
    "SessionUploads",
    "offered_folders",
    "session_uploads",
    "sweep",
    "upload_root",
]
