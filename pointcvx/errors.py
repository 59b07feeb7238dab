"""Typed exceptions raised by pointcvx.

Every error a user can cause with their input derives from :class:`PointcvxError`, so API callers
catch one type and the CLI turns it into a one-line message and a non-zero exit.
"""

from __future__ import annotations


class PointcvxError(Exception):
    """Base class of every error pointcvx raises on purpose."""


class InputError(PointcvxError, ValueError):
    """The input exists but cannot be used (empty, corrupted, degenerate, non-finite...)."""


class UnknownFormatError(InputError):
    """The file's content matches no format pointcvx can read."""


class MissingExtraError(PointcvxError, ImportError):
    """An optional dependency is needed for this input (install the named extra)."""

    def __init__(self, feature: str, extra: str, module: str):
        self.feature, self.extra, self.module = feature, extra, module
        super().__init__(
            f"{feature} needs the optional package '{module}': pip install 'pointcvx[{extra}]'"
        )


class OutputError(PointcvxError, OSError):
    """An output cannot be written (exists without overwrite, unwritable directory...)."""


class MissingLibraryError(PointcvxError, ImportError):
    """A system shared library that a dependency's binary wheel links is not installed."""

    def __init__(self, module: str, library: str, hint: str):
        self.module, self.library, self.hint = module, library, hint
        super().__init__(f"{module} needs the system library {library}, which this machine lacks: {hint}")
