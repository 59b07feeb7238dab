"""Flag choices read from the module that owns them, only when a command checks or shows them.

``pointcvx --help`` builds every sub-command's parser; a flag whose choices live in a heavy
module (the output formats of :mod:`pointcvx.export`, the engines of :mod:`pointcvx.apps.batch`)
would import it, and numpy with it, just to list the commands. :class:`LazyChoices` stands in
for the tuple: argparse reads it (``in``, iteration) only when it parses that flag or prints
that sub-command's help. Give such a flag a ``metavar``, since argparse otherwise spells the
choices out while the parser is built; ``%(choices)s`` in its help lists them when shown.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Sequence


class LazyChoices(Sequence):
    """The tuple ``module.attribute``, imported on first use.

    Parameters
    ----------
    module : str
        Absolute module name, e.g. ``"pointcvx.export"``.
    attribute : str
        The name of the tuple (or any sequence) in that module.
    """

    def __init__(self, module: str, attribute: str):
        self.module, self.attribute = module, attribute
        self._values: tuple | None = None

    @property
    def values(self) -> tuple:
        if self._values is None:
            self._values = tuple(getattr(importlib.import_module(self.module), self.attribute))
        return self._values

    def __getitem__(self, index):
        return self.values[index]

    def __len__(self) -> int:
        return len(self.values)

    def __contains__(self, value: object) -> bool:
        return value in self.values

    def __iter__(self) -> Iterator:
        return iter(self.values)

    def __repr__(self) -> str:
        return f"LazyChoices({self.module}.{self.attribute})"
