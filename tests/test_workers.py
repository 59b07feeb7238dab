"""Worker threads (pointcvx.workers): pmap keeps order, raises, runs serially where it must, and a
decomposition gives the same hulls with one thread or several."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest
from shapes import l_block

import pointcvx
from pointcvx import workers


@pytest.fixture
def two_threads():
    workers.set_threads(2)
    yield
    workers.set_threads(None)


def test_pmap_keeps_the_order_of_its_items_and_runs_two_at_once(two_threads):
    assert workers.pmap(lambda x: x * x, range(50)) == [x * x for x in range(50)]
    # The first two calls wait for each other: they return only if two threads run them at once.
    meet = threading.Barrier(2, timeout=30)
    names = workers.pmap(lambda x: (meet.wait(), threading.current_thread().name)[1] if x < 2
                         else threading.current_thread().name, range(6))
    assert len(set(names[:2])) == 2 and any(n.startswith("pointcvx") for n in names), names


def test_pmap_raises_the_first_callers_exception(two_threads):
    def fail_on_three(x):
        if x == 3:
            raise ValueError("three")
        return x

    with pytest.raises(ValueError, match="three"):
        workers.pmap(fail_on_three, range(8))
    assert workers.pmap(abs, [-1, -2, -3]) == [1, 2, 3]  # the pool still serves


def test_one_thread_and_nested_maps_run_in_the_caller():
    workers.set_threads(1)
    try:
        assert {t for t in workers.pmap(lambda _: threading.current_thread().name, range(4))} == {
            threading.current_thread().name}
    finally:
        workers.set_threads(None)
    workers.set_threads(2)
    try:
        # A map inside a map would wait on its own pool: it runs where its caller runs.
        inner = workers.pmap(lambda _: {t for t in workers.pmap(
            lambda _: threading.current_thread().name, range(4))}, range(8))
        assert all(len(names) == 1 for names in inner), inner
    finally:
        workers.set_threads(None)


def test_thread_count_follows_the_setting_then_omp_num_threads(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert workers.threads() == 3
    monkeypatch.setenv("OMP_NUM_THREADS", "64")
    assert workers.threads() == workers.MAX_THREADS
    workers.set_threads(1)
    try:
        assert workers.threads() == 1
    finally:
        workers.set_threads(None)
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert 1 <= workers.threads() <= workers.MAX_THREADS


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork is POSIX")
def test_a_forked_child_gets_its_own_pool(two_threads):
    assert workers.pmap(abs, [-1, -2]) == [1, 2]  # the parent's pool exists now
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: the parent's threads are gone, a new pool must serve it
        try:
            ok = workers.pmap(abs, [-3, -4, -5]) == [3, 4, 5]
            os.write(w, b"1" if ok else b"0")
        finally:
            os._exit(0)
    os.close(w)
    got = os.read(r, 1)
    os.waitpid(pid, 0)
    assert got == b"1"


def _hulls(threads):
    workers.set_threads(threads)
    try:
        result = pointcvx.decompose(l_block(), threshold=0.05, n_points=6000, seed=0)
    finally:
        workers.set_threads(None)
    return result


def test_one_thread_and_two_give_the_same_decomposition():
    one, two = _hulls(1), _hulls(2)
    assert len(one.hulls) == len(two.hulls) >= 2
    for a, b in zip(one.hulls, two.hulls, strict=True):
        assert np.array_equal(a.vertices, b.vertices)
    assert np.array_equal(one.labels, two.labels)
    assert np.array_equal(one.concavity, two.concavity)


def test_batch_and_bench_workers_thread_share_sets_the_worker_count():
    """``apps.common.limit_threads`` (a batch or bench worker's thread share) sets the worker
    threads too; in its own process, since it also fixes the process's BLAS threads."""
    import subprocess
    import sys

    code = ("from pointcvx.apps.common import limit_threads; from pointcvx import workers; "
            "before = workers.threads(); limit_threads(1); print(before, workers.threads())")
    env = {**os.environ, "OMP_NUM_THREADS": "2"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         check=True, timeout=120).stdout.split()
    assert out == ["2", "1"], out


def test_kd_queries_use_the_threads_outside_maps_only(two_threads):
    """A large kd-tree query made by the main thread spreads over the process's threads; inside
    a map (whose other threads are busy) and for a small query it stays on one; the neighbours
    are the same either way."""
    from scipy.spatial import cKDTree

    big = workers.KD_MIN_QUERIES
    assert workers.kd_workers(big) == 2 and workers.kd_workers(big - 1) == 1
    assert workers.pmap(lambda n: workers.kd_workers(n), [big, big]) == [1, 1]
    pts = np.random.default_rng(0).random((big, 3))
    tree = cKDTree(pts)
    one, many = tree.query(pts, k=8, workers=1), tree.query(pts, k=8, workers=workers.kd_workers(big))
    np.testing.assert_array_equal(one[0], many[0])
    np.testing.assert_array_equal(one[1], many[1])
    workers.set_threads(1)
    assert workers.kd_workers(10 * big) == 1
