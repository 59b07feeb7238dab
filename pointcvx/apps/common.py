"""What the batch and bench applications share: shape files, worker threads, peak memory, and
stopping pool workers whose parent is gone."""

from __future__ import annotations

import resource
import sys

from ..errors import PointcvxError

SHAPE_SUFFIXES = frozenset({
    ".obj", ".ply", ".stl", ".off", ".glb", ".gltf", ".step", ".stp", ".iges", ".igs",
    ".spz", ".splat", ".pcd", ".xyz", ".pts", ".las", ".laz",
})
"""File name endings taken as shapes from a folder (README, .md, .txt, .json... are skipped)."""


def limit_threads(threads: int | None) -> None:
    """Fix this process's BLAS, torch and worker (:mod:`pointcvx.workers`) thread counts
    (None or 0: leave them)."""
    if not threads:
        return
    from threadpoolctl import threadpool_limits

    from ..workers import set_threads

    set_threads(int(threads))
    threadpool_limits(int(threads))
    if "torch" in sys.modules:  # torch reads its own setting; set it once it is imported
        sys.modules["torch"].set_num_threads(int(threads))
    else:
        import os

        os.environ["OMP_NUM_THREADS"] = str(int(threads))


def peak_kb() -> int:
    """Peak resident memory of this process so far, in KiB.

    On Linux this is ``VmHWM`` of ``/proc/self/status``: unlike ``ru_maxrss``, which a process
    started by fork + exec inherits from its parent (often a larger peak), it belongs to this
    program alone. Elsewhere: ``ru_maxrss`` (bytes on macOS, KiB otherwise).
    """
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss // 1024 if sys.platform == "darwin" else rss


class Orphaned(PointcvxError):
    """The process that started this pool worker is gone: start no more work."""


def stop_if_orphaned() -> None:
    """Raise :class:`Orphaned` in a pool worker whose parent died (killed or interrupted), so
    that an abandoned worker does not go on launching work."""
    import multiprocessing

    parent = multiprocessing.parent_process()
    if parent is not None and not parent.is_alive():
        raise Orphaned("the process that started this worker has stopped")
