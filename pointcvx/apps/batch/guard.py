"""The resource guard of a worker: one asset's time and resident-memory limits, enforced by
interrupting it, and, if it does not stop, by exiting the worker."""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import sys
import threading
import time

from ...errors import PointcvxError

log = logging.getLogger(__name__)

GRACE = 10.0
"""Seconds a worker gets to stop an asset past its limit before it exits; the driver kills a
worker still busy with the asset :data:`GRACE` seconds after that."""

EXIT_TIMEOUT, EXIT_MEMORY = 124, 125
"""Exit statuses of a worker that had to exit to stop an asset over its time or memory limit."""

MEMORY_SHARE = 0.8
"""Default memory limit: this share of the machine's memory, split evenly between its workers."""


class AssetTimeout(PointcvxError):
    """An asset ran past its time limit."""


class AssetMemoryError(PointcvxError):
    """A worker's resident memory went over its limit while running an asset."""


def rss_mb() -> float:
    """Resident memory of this process in MB (0 where it cannot be read)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


def reset_peak() -> bool:
    """Reset this process's peak resident memory (Linux ``clear_refs``); False if it cannot."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def machine_memory_mb() -> float:
    """Physical memory of this machine in MB (0 if unknown)."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (ValueError, OSError, AttributeError):
        return 0.0


class Guard:
    """Watch the calling thread while it runs one asset: past ``timeout`` seconds or over
    ``max_mb`` of resident memory, raise :class:`AssetTimeout` / :class:`AssetMemoryError` in it
    (an asynchronous exception, delivered between two Python bytecodes); if it has not stopped
    :data:`GRACE` seconds later (stuck in native code), exit the process with
    :data:`EXIT_TIMEOUT` / :data:`EXIT_MEMORY` so that its driver records the failure and starts a
    fresh worker."""

    def __init__(self, timeout: float, max_mb: float | None, interval: float = 0.1):
        self.timeout, self.max_mb, self.interval = float(timeout), max_mb or None, interval
        self.reason = ""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._fired = False
        self._thread: threading.Thread | None = None
        self._target = threading.get_ident()
        self.started = time.monotonic()

    def start(self) -> Guard:
        self._target = threading.get_ident()
        self.started = time.monotonic()
        self._thread = threading.Thread(target=self._watch, name="pointcvx-batch-guard", daemon=True)
        self._thread.start()
        return self

    def _watch(self) -> None:
        while not self._stop.wait(self.interval):
            elapsed = time.monotonic() - self.started
            if elapsed > self.timeout:
                self._fire(AssetTimeout, f"timeout after {self.timeout:g} s", EXIT_TIMEOUT)
                return
            if self.max_mb is not None:
                rss = rss_mb()
                if rss > self.max_mb:
                    self._fire(AssetMemoryError, f"memory limit: {rss:.0f} MB resident, over the "
                               f"limit of {self.max_mb:.0f} MB", EXIT_MEMORY)
                    return

    def _fire(self, exc_type: type, reason: str, code: int) -> None:
        with self._lock:
            if self._stop.is_set():
                return
            self._fired = True
            self.reason = reason
            ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._target),
                                                       ctypes.py_object(exc_type))
        log.warning("%s; stopping the asset", reason)
        if not self._stop.wait(GRACE):
            log.error("%s and the asset did not stop within %g s: the worker exits", reason, GRACE)
            with contextlib.suppress(Exception):
                sys.stderr.flush()
            os._exit(code)

    def stop(self) -> None:
        """Stop watching (idempotent); a limit's exception not yet delivered is withdrawn."""
        with self._lock:
            self._stop.set()
            if self._fired:
                ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._target), None)
