"""Progress bars on stderr (tqdm), created on first use so that quiet runs never import tqdm."""

from __future__ import annotations

import sys


class LazyBar:
    """One tqdm bar, made on the first :meth:`set`; a no-op when ``enabled`` is false.

    Parameters
    ----------
    enabled : bool
    desc, unit : str, the bar's label and unit.
    leave : bool, keep the finished bar on screen.
    """

    def __init__(self, enabled: bool, desc: str, unit: str, leave: bool = False):
        self.enabled, self.desc, self.unit, self.leave = enabled, desc, unit, leave
        self.bar = None

    def set(self, done: int, total: int, postfix: str | None = None) -> None:
        """Show ``done`` of ``total`` (never moves backwards), with an optional postfix."""
        if not self.enabled:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=self.desc, unit=self.unit, file=sys.stderr,
                            leave=self.leave, dynamic_ncols=True)
        self.bar.update(max(0, min(done, total) - self.bar.n))
        if postfix:
            self.bar.set_postfix_str(postfix, refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class StageBars:
    """One :class:`LazyBar` per pipeline stage, as a ``progress(stage, done, total)`` callback.

    Stages run one after the other ("features", "split", a scene's "object 2/3 features", or
    its "objects" when they run at once):
    a new stage closes the bars before it, so one bar is on screen at a time.
    """

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.bars: dict[str, LazyBar] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        if stage not in self.bars:
            self.close()
            unit = "step" if stage.endswith("features") else "object" if stage == "objects" else "hull"
            self.bars[stage] = LazyBar(self.enabled, stage, unit)
        self.bars[stage].set(done, total)

    def close(self) -> None:
        for bar in self.bars.values():
            bar.close()
