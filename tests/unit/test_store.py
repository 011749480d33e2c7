"""The results store: round trip, atomic writes, corrupt files, oldest-out bound, concurrency."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from navlab import store as ST
from navlab.errors import NavlabError


def _arrays(i: int) -> dict[str, np.ndarray]:
    return {"a": np.arange(1000, dtype=float) + i, "b/c": np.array([True, False])}


def test_round_trip_and_no_temporary_left(tmp_path):
    s = ST.Store(tmp_path)
    k = ST.key_of({"x": 1})
    assert s.get(k) is None
    s.put(k, {"what": "test"}, _arrays(1))
    head, arr = s.get(k)
    assert head["what"] == "test" and head["key"] == k
    np.testing.assert_array_equal(arr["a"], _arrays(1)["a"])
    np.testing.assert_array_equal(arr["b/c"], [True, False])
    assert not list(tmp_path.rglob(".tmp-*"))


def test_key_depends_on_configuration_and_version(monkeypatch):
    k1 = ST.key_of({"x": 1})
    assert ST.key_of({"x": 2}) != k1
    assert ST.key_of({"x": 1}) == k1
    monkeypatch.setattr(ST, "__version__", "999.0")
    assert ST.key_of({"x": 1}) != k1
    monkeypatch.undo()
    assert ST.key_of({"x": 1}) == k1
    monkeypatch.setattr(ST, "code_id", lambda: "0" * 64)  # a changed source file, same version
    assert ST.key_of({"x": 1}) != k1


def test_code_id_hashes_the_package_sources():
    assert len(ST.code_id()) == 64 and ST.code_id() == ST.code_id()


def test_a_corrupt_file_is_missing_and_removed(tmp_path):
    s = ST.Store(tmp_path)
    k = ST.key_of("corrupt")
    s.put(k, {}, _arrays(0))
    p = s.path(k)
    p.write_bytes(p.read_bytes()[:100])  # cut short
    assert s.get(k) is None
    assert not p.exists()
    s.put(k, {}, _arrays(0))
    p.write_bytes(b"")  # empty (a disk that filled up): was 'internal error: EOFError'
    assert s.get(k) is None
    assert not p.exists()


def test_size_bound_removes_the_least_recently_used(tmp_path):
    s = ST.Store(tmp_path, max_bytes=10**9)
    keys = [ST.key_of(i) for i in range(5)]
    for i, k in enumerate(keys):
        s.put(k, {}, _arrays(i))
        os.utime(s.path(k), (1000 + i, 1000 + i))  # k0 oldest … k4 newest
    os.utime(s.path(keys[0]), (2000, 2000))  # k0 used recently: now k1 is the oldest
    one = s.path(keys[0]).stat().st_size
    s.prune(max_bytes=int(3.5 * one))
    left = [k for k in keys if k in s]
    assert left == [keys[0], keys[3], keys[4]]
    assert s.size() <= 3.5 * one


def test_off_and_unwritable(tmp_path, monkeypatch):
    monkeypatch.setenv(ST.ENV_DIR, "off")
    s = ST.Store.open()
    assert s.root is None
    s.put("k", {}, _arrays(0))  # a no-op
    assert s.get("k") is None
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(NavlabError, match="cannot create the results store"):
        ST.Store(blocker / "sub")
    with pytest.raises(NavlabError, match="a file, not a folder"):  # was 'File exists'
        ST.Store(blocker)


def test_concurrent_writers_and_readers(tmp_path):
    s1, s2 = ST.Store(tmp_path), ST.Store(tmp_path)  # two sessions on one folder
    keys = [ST.key_of(("c", i % 4)) for i in range(40)]
    errors: list[BaseException] = []

    def work(s: ST.Store, off: int) -> None:
        try:
            for i, k in enumerate(keys):
                s.put(k, {"i": i % 4}, _arrays(i % 4))
                got = s.get(keys[(i + off) % len(keys)])
                if got is not None:  # a reader sees a whole file or none
                    head, arr = got
                    np.testing.assert_array_equal(arr["a"], _arrays(head["i"])["a"])
        except BaseException as exc:
            errors.append(exc)

    ts = [threading.Thread(target=work, args=(s, j)) for j, s in enumerate((s1, s2, s1, s2))]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert not errors
    assert all(s1.get(k) is not None for k in keys)
    assert not list(tmp_path.rglob(".tmp-*"))


def test_a_damaged_entry_of_any_form_is_discarded_and_recomputed(tmp_path):
    """Issue 22 item 8: a folder at an entry's path gave 'internal error: IsADirectoryError'; an
    entry with the right header but arrays cut to half length gave 'could not broadcast' on every
    rerun. Both are now removed and recomputed, with the numbers of the first computation."""
    from navlab import tasks as T
    from navlab.experiment import ExperimentSpec

    spec = ExperimentSpec(filters=("kf", "chi2-kf"), runs=6, seed=3, epochs=20, contamination=0.1)
    tasks = [t for v in T.tasks_for(spec, block=3).values() for t in v]
    s = ST.Store(tmp_path)
    first = T.compute(tasks, store=s)
    calls: list[str] = []

    def counted(task):
        calls.append(task.key)
        return T.run_task(task)

    assert T.compute(tasks, store=s, task_fn=counted).keys() == first.keys() and calls == []  # all hits
    folder, short = tasks[0].key, tasks[1].key
    s.path(folder).unlink()
    (s.path(folder) / "inside").mkdir(parents=True)  # a folder in its place
    head, arrays = s.get(short)
    s.put(
        short,
        {k: v for k, v in head.items() if k not in ("key", "navlab")},
        {k: v[: len(v) // 2] for k, v in arrays.items()},
    )  # the right header, arrays cut to half length
    again = T.compute(tasks, store=s, task_fn=counted)
    assert sorted(calls) == sorted([folder, short])
    for k in (folder, short):
        np.testing.assert_array_equal(again[k].stats.diverged, first[k].stats.diverged)
        for name, v in first[k].stats.sse.items():
            np.testing.assert_array_equal(again[k].stats.sse[name], v)
    assert s.path(folder).is_file() and s.get(short) is not None
    calls.clear()
    T.compute(tasks, store=s, task_fn=counted)
    assert calls == []  # mended for good
