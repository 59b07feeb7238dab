"""Threads for independent pieces of one decomposition: the concavity measures of a split's
proposals and of a merge's candidate pairs, the row chunks of the fit's steps.

Each piece is a pure function of its input (its own seeded samples, no shared state), so the
results are the same with one thread or several; only the time changes. The heavy parts of a
piece (Qhull, ray casts, NumPy's array loops and single-threaded BLAS) run without Python's
lock: on two cores a warm decomposition's split and merge take 0.7-1.0x and its fit 0.85-0.9x
the time of one thread (docs/benchmarks.md, "Two cores").

How many: :func:`set_threads` (``pointcvx batch`` and ``bench`` workers, from their thread
share), else ``OMP_NUM_THREADS`` when set (the usual way to keep a process to one core), else
the CPUs this process may run on, at most :data:`MAX_THREADS`.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")

#: The most threads used by default (a split has a handful of proposals, a merge some dozens of
#: pairs: more threads than pieces only wait).
MAX_THREADS = 8

_setting: int | None = None
_pool: tuple[int, int, ThreadPoolExecutor] | None = None  # (pid, threads, executor)
_local = threading.local()


def set_threads(threads: int | None) -> None:
    """Use at most ``threads`` threads (None: the default of the module docstring)."""
    global _setting
    _setting = None if threads is None else max(1, int(threads))


def threads() -> int:
    """How many threads :func:`pmap` uses now (1: it runs in the caller)."""
    if _setting is not None:
        return _setting
    env = os.environ.get("OMP_NUM_THREADS", "").strip()
    if env.isdigit() and int(env) > 0:
        return min(int(env), MAX_THREADS)
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cpus = os.cpu_count() or 1
    return max(1, min(cpus, MAX_THREADS))


def _executor(n: int) -> ThreadPoolExecutor:
    """The process's pool of ``n`` threads: kept while ``n`` stays, replaced when the setting
    changes, and new after a fork (threads do not survive it)."""
    global _pool
    pid = os.getpid()
    if _pool is None or _pool[0] != pid or _pool[1] != n:
        if _pool is not None and _pool[0] == pid:
            _pool[2].shutdown(wait=False)
        _pool = (pid, n, ThreadPoolExecutor(n, thread_name_prefix="pointcvx"))
    return _pool[2]


def pmap(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(x) for x in items]``, the calls spread over :func:`threads` threads (the caller and
    ``threads() - 1`` of the pool's, each taking the next item when it is free), results in
    order. The exception of the first item that raised is raised here, after every started call
    has returned. Serial with one thread, one item, or inside another map (a nested map would
    wait on its own pool)."""
    items = list(items)
    n = min(threads(), len(items))
    if n <= 1 or getattr(_local, "inside", False):
        return [fn(x) for x in items]
    results: list = [None] * len(items)
    errors: dict[int, BaseException] = {}
    order = iter(range(len(items)))
    lock = threading.Lock()

    def drain() -> None:
        _local.inside = True
        try:
            while not errors:
                with lock:
                    k = next(order, None)
                if k is None:
                    return
                try:
                    results[k] = fn(items[k])
                except BaseException as error:  # raised in the caller below
                    errors[k] = error
        finally:
            _local.inside = False

    pool = _executor(threads() - 1)  # one size for every map, however many items it has
    helpers = [pool.submit(drain) for _ in range(n - 1)]
    drain()
    for helper in helpers:
        helper.result()
    if errors:
        raise errors[min(errors)]
    return results


def even_slices(n: int, chunks: int) -> list[slice]:
    """``chunks`` consecutive slices of ``range(n)`` as even as can be (the empty ones left out):
    the runs of rows that :func:`pmap` spreads over its threads."""
    chunks = max(int(chunks), 1)
    cuts = [n * i // chunks for i in range(chunks + 1)]
    return [slice(lo, hi) for lo, hi in zip(cuts[:-1], cuts[1:], strict=True) if hi > lo]


#: Queries below which a kd-tree query stays on one thread (its threads cost more than they save).
KD_MIN_QUERIES = 4096


def kd_workers(n_queries: int) -> int:
    """``workers`` for a ``cKDTree.query`` of ``n_queries`` points: :func:`threads` for a large
    query made outside :func:`pmap`'s threads, else 1 (inside a map the other threads are
    busy). Each point's neighbours are found on their own, so the answer is the same with any
    number of workers."""
    if n_queries < KD_MIN_QUERIES or getattr(_local, "inside", False):
        return 1
    return threads()
