"""The worker pools a batch runs on: spawned local processes or Ray actors, one asset at a time
each, behind one interface (start, submit, poll, kill, close)."""

from __future__ import annotations

import contextlib
import logging
import os
import re
import sys
import time
from dataclasses import dataclass
from typing import Any

from ...errors import InputError, MissingExtraError, first_line
from .guard import EXIT_MEMORY, EXIT_TIMEOUT
from .options import BatchOptions
from .worker import BatchActor, local_worker


@dataclass
class _Event:
    """What :meth:`poll` reports about the worker in ``slot``."""

    slot: int
    kind: str  # "ready", "result", "died" (worker gone), "error" (worker could not start)
    value: Any = None


class LocalPool:
    """``jobs`` spawned processes running :func:`~pointcvx.apps.batch.worker.local_worker`, one
    asset at a time each."""

    name = "local"

    def __init__(self, jobs: int, options: BatchOptions, outdir: str):
        import multiprocessing

        self.ctx = multiprocessing.get_context("spawn")
        self.jobs, self.outdir = jobs, outdir
        self.options = options.to_dict()
        self.procs: list[Any] = [None] * jobs
        self.conns: list[Any] = [None] * jobs
        self.busy: set[int] = set()

    def start(self, i: int) -> None:
        parent, child = self.ctx.Pipe()
        proc = self.ctx.Process(target=local_worker, args=(child, self.options, self.outdir, self.jobs),
                                name=f"pointcvx-batch-{i}")
        proc.start()
        child.close()
        self.procs[i], self.conns[i] = proc, parent

    def submit(self, i: int, task: dict) -> None:
        self.busy.add(i)
        try:
            self.conns[i].send(task)
        except OSError:  # it died since: poll() reports it
            pass

    def poll(self, timeout: float) -> list[_Event]:
        from multiprocessing.connection import wait

        watch = {}
        for i, (proc, conn) in enumerate(zip(self.procs, self.conns, strict=True)):
            if proc is not None:
                watch[conn] = i
                watch[proc.sentinel] = i
        events: list[_Event] = []
        ready = set()
        for obj in wait(list(watch), timeout):
            ready.add(watch[obj])
        for i in sorted(ready):
            proc, conn = self.procs[i], self.conns[i]
            try:
                while conn.poll():
                    kind, value = conn.recv()
                    events.append(_Event(i, kind, value))
                    self.busy.discard(i)
            except (EOFError, OSError):
                pass
            if any(e.slot == i and e.kind == "error" for e in events):
                self._drop(i)
                continue
            if not proc.is_alive():
                proc.join(timeout=1.0)
                events.append(_Event(i, "died", _exit_reason(proc.exitcode)))
                self._drop(i)
        return events

    def _drop(self, i: int) -> None:
        proc, conn = self.procs[i], self.conns[i]
        if proc is not None and proc.is_alive():
            proc.kill()
        if proc is not None:
            proc.join(timeout=5)
        if conn is not None:
            conn.close()
        self.procs[i] = self.conns[i] = None
        self.busy.discard(i)

    def kill(self, i: int) -> None:
        self._drop(i)

    def close(self) -> None:
        """Stop every worker: idle ones are told to exit, busy ones (an interrupted batch) are
        killed."""
        for i in list(self.busy):
            self._drop(i)
        for conn in self.conns:
            if conn is not None:
                with contextlib.suppress(OSError):
                    conn.send(None)
        deadline = time.monotonic() + 5.0
        for i, proc in enumerate(self.procs):
            if proc is not None:
                proc.join(timeout=max(0.0, deadline - time.monotonic()))
                self._drop(i)


def _exit_reason(code: int | None) -> str:
    if code == EXIT_TIMEOUT:
        return "worker exited to stop an asset past its timeout"
    if code == EXIT_MEMORY:
        return "worker exited to stop an asset over its memory limit"
    if code is not None and code < 0:
        import signal

        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"worker died ({name})"
    return f"worker died (exit status {code})"


def import_ray():
    """The ``ray`` module; :class:`~pointcvx.errors.MissingExtraError` without it."""
    try:
        import ray
    except ImportError:
        raise MissingExtraError("--engine ray", "ray", "ray") from None
    return ray


class RayPool:
    """``jobs`` Ray actors (:class:`~pointcvx.apps.batch.worker.BatchActor`, ``threads`` CPUs
    each), one asset at a time each."""

    name = "ray"

    def __init__(self, jobs: int, options: BatchOptions, outdir: str):
        ray = import_ray()
        self.ray = ray
        self.actor_cls = ray.remote(num_cpus=options.threads, max_restarts=0)(BatchActor)
        self.options = options.to_dict()
        self.outdir = outdir
        self.actors: list[Any] = [None] * jobs
        self.refs: dict[Any, tuple[int, str]] = {}

    def start(self, i: int) -> None:
        actor = self.actor_cls.remote(self.options, self.outdir)
        self.actors[i] = actor
        self.refs[actor.ready.remote()] = (i, "ready")

    def submit(self, i: int, task: dict) -> None:
        self.refs[self.actors[i].run.remote(task)] = (i, "result")

    def poll(self, timeout: float) -> list[_Event]:
        ray = self.ray
        if not self.refs:
            time.sleep(timeout)
            return []
        ready, _ = ray.wait(list(self.refs), num_returns=1, timeout=timeout)
        if ready:
            more, _ = ray.wait([r for r in self.refs if r not in ready], num_returns=len(self.refs) - 1,
                               timeout=0) if len(self.refs) > 1 else ([], [])
            ready = ready + more
        events = []
        for ref in ready:
            i, kind = self.refs.pop(ref)
            try:
                value = ray.get(ref)
            except ray.exceptions.RayActorError as exc:
                events.append(_Event(i, "died", _ray_reason(exc)))
                self._drop(i)
                continue
            except ray.exceptions.RayError as exc:
                events.append(_Event(i, "died", f"worker failed: {first_line(exc, typed=True)}"))
                self._drop(i)
                continue
            if kind == "ready":
                events.append(_Event(i, value[0], value[1]))
                if value[0] == "error":
                    self._drop(i)
            else:
                events.append(_Event(i, "result", value))
        return events

    def _drop(self, i: int) -> None:
        actor = self.actors[i]
        if actor is not None:
            with contextlib.suppress(Exception):
                self.ray.kill(actor, no_restart=True)
        self.actors[i] = None
        for ref in [r for r, (j, _) in self.refs.items() if j == i]:
            del self.refs[ref]

    def kill(self, i: int) -> None:
        self._drop(i)

    def close(self) -> None:
        for i in range(len(self.actors)):
            self._drop(i)


def _ray_reason(exc: BaseException) -> str:
    text = str(exc)
    m = re.search(r"Worker exit detail: ([^.]+)", text)
    return "worker died" + (f" ({m.group(1).strip()})" if m else "")


@contextlib.contextmanager
def ray_session(address: str | None, num_cpus: int | None = None):
    """Connect to the Ray cluster at ``address`` (``auto``, ``ray://...``, ``HOST:PORT``), or start
    a local instance on the loopback interface (``num_cpus`` CPUs; stopped on exit), or use the one
    this process already joined. Yields the ``ray`` module."""
    started_here = False
    env_key = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
    saved_env = os.environ.get(env_key)
    if "ray" not in sys.modules and address is None:
        # A local instance serves only this batch: keep every Ray port on 127.0.0.1.
        os.environ[env_key] = "0"
    ray = import_ray()
    try:
        if not ray.is_initialized():
            kwargs = {"log_to_driver": False, "logging_level": logging.ERROR}
            if address is None:
                kwargs.update(address="local", include_dashboard=False,
                              num_cpus=num_cpus or os.cpu_count() or 1)
            else:
                kwargs["address"] = address
            try:
                ray.init(**kwargs)
            except (ConnectionError, ValueError, RuntimeError) as exc:
                where = address or "a local instance"
                raise InputError(f"cannot start Ray on {where}: {first_line(exc, typed=True)}") from None
            started_here = True
        yield ray
    finally:
        if started_here:
            ray.shutdown()
        if address is None and saved_env is None:
            os.environ.pop(env_key, None)
