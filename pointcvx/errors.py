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
    """A package is needed for this input: the named extra's, or (``extra=None``) a dependency
    that is not installed."""

    def __init__(self, feature: str, extra: str | None, module: str):
        self.feature, self.extra, self.module = feature, extra, module
        if extra is None:
            message = (f"{feature} need the package '{module}', a dependency of pointcvx that is "
                       f"not installed: pip install {module}")
        else:
            message = f"{feature} needs the optional package '{module}': pip install 'pointcvx[{extra}]'"
        super().__init__(message)


class OutputError(PointcvxError, OSError):
    """An output cannot be written (exists without overwrite, unwritable directory...)."""


class MissingLibraryError(PointcvxError, ImportError):
    """A system shared library that a dependency's binary wheel links is not installed."""

    def __init__(self, module: str, library: str, hint: str):
        self.module, self.library, self.hint = module, library, hint
        super().__init__(f"{module} needs the system library {library}, which this machine lacks: {hint}")


class TimeLimitError(PointcvxError, TimeoutError):
    """A decomposition ran past its ``timeout``; nothing was written."""


#: Exit statuses of the ``pointcvx`` command.
EXIT_OK, EXIT_INPUT, EXIT_USAGE, EXIT_INTERNAL, EXIT_INTERRUPT = 0, 1, 2, 3, 130


def first_line(exc: BaseException, limit: int = 300, typed: bool = False) -> str:
    """The first line of ``exc``'s message, at most ``limit`` characters: how every error is
    summarised in one line (CLI, batch records, bench rows). ``typed`` prefixes the exception's
    type (``ValueError: ...``); a message-less exception is its type's name."""
    text = str(exc).strip()
    line = text.splitlines()[0] if text else ""
    if typed or not line:
        line = f"{type(exc).__name__}: {line}" if line else type(exc).__name__
    return line if len(line) <= limit else line[: limit - 3] + "..."
