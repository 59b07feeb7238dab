"""A time limit on one decomposition (``decompose(timeout=...)``, ``pointcvx decompose --timeout``).

- :meth:`Deadline.check` is called between stages and from every progress report (each feature
  optimisation step, each split): the API's limit, which ends a decomposition within one step
  of it with :class:`~pointcvx.errors.TimeLimitError`. Loading has no steps; its work is bounded
  by what the loaders accept (:mod:`pointcvx.io`).
- :func:`watchdog` backs the command line: a timer thread that ends the process shortly after
  the limit if no check has (one line on stderr, exit 1, nothing written).
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable, Iterator

from .errors import TimeLimitError


class Deadline:
    """``seconds`` (None: no limit) from now, as :func:`time.monotonic` measures.

    Attributes
    ----------
    seconds : float or None
    start : float, monotonic time of creation
    stage : str, what was running at the last check (named in the error)
    """

    def __init__(self, seconds: float | None):
        self.seconds = None if seconds is None else float(seconds)
        self.start = time.monotonic()
        self.stage = "loading"

    def left(self) -> float:
        """Seconds left (inf without a limit; negative once past it)."""
        if self.seconds is None:
            return math.inf
        return self.seconds - (time.monotonic() - self.start)

    def error(self) -> TimeLimitError:
        return TimeLimitError(f"stopped after the time limit of {self.seconds:g} s "
                              f"(while {self.stage}); nothing was written")

    def check(self, stage: str | None = None) -> None:
        """Record ``stage`` and raise :class:`TimeLimitError` when the time is up."""
        if stage is not None:
            self.stage = stage
        if self.left() <= 0:
            raise self.error()

    def watch(self, progress: Callable | None) -> Callable | None:
        """A ``progress(stage, done, total)`` callback that checks the deadline, then forwards
        to ``progress`` (None without a limit and without ``progress``)."""
        if self.seconds is None:
            return progress

        def report(stage: str, done: int, total: int) -> None:
            self.check(stage)
            if progress is not None:
                progress(stage, done, total)

        return report



@contextlib.contextmanager
def watchdog(seconds: float | None, expire: Callable[[], None]) -> Iterator[None]:
    """Call ``expire()`` from a daemon thread if the block is still running after ``seconds``
    (nothing without a limit). For the command line, whose ``expire`` ends the process: a
    Python-level interruption (a signal raising inside library code) can leave a C extension's
    state broken, and libraries' ``except BaseException`` swallow it."""
    if seconds is None:
        yield
        return
    timer = threading.Timer(seconds, expire)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
