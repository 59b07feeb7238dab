"""Command-line flags made from the option declarations (:mod:`pointcvx.options`), and the
parser whose usage errors are one line and exit status 2.

Every command that takes decomposition or loading options (``info``, ``decompose``, ``batch``,
``bench``) adds them with :func:`add_flags` and reads them back with :func:`options_from_args`,
so a flag parses and checks its value exactly as the API does.
"""

from __future__ import annotations

import argparse
import os
from dataclasses import fields
from typing import Any

from .errors import EXIT_USAGE, InputError
from .options import Options, Spec, check_value, spec_of


class UsageParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line on stderr and exit status 2."""

    def error(self, message: str) -> None:
        self.exit(EXIT_USAGE, f"pointcvx: error: {message} (see pointcvx --help)\n")


_KIND_NAMES = {int: "an integer", float: "a number", str: "a string", os.PathLike: "a path",
               tuple: "comma-separated numbers"}


def parse_value(name: str, spec: Spec):
    """The argparse ``type`` of an option: text -> checked value, or a usage error."""

    def parse(text: str) -> Any:
        try:
            if spec.kind is tuple:
                value = tuple(float(x) for x in text.split(","))
            elif spec.length and not _is_number(text):
                value = text  # a length with a unit: checked below
            else:
                value = spec.kind(text) if spec.kind in (int, float) else text
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {_KIND_NAMES[spec.kind]}, got {text!r}") from None
        try:
            return check_value(name, spec, value)
        except InputError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = _KIND_NAMES[spec.kind]
    return parse


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _group(parser: argparse.ArgumentParser, title: str):
    groups = parser.__dict__.setdefault("_pointcvx_groups", {})
    if title not in groups:
        groups[title] = parser.add_argument_group(title)
    return groups[title]


def add_flags(parser: argparse.ArgumentParser, options: type[Options], *, skip: tuple[str, ...] = (),
              defaults: dict[str, Any] | None = None) -> None:
    """Add a flag for every option of ``options`` that declares one (except ``skip``).

    ``defaults`` overrides declared defaults for this command (``decompose`` caps the points).
    A boolean option whose default is True becomes ``--no-NAME``.
    """
    defaults = defaults or {}
    for f in fields(options):
        spec = spec_of(f)
        if spec.flag is None or f.name in skip:
            continue
        where = _group(parser, spec.group) if spec.group else parser
        default = defaults.get(f.name, f.default)
        if spec.kind is bool:
            if default:
                where.add_argument(f"--no-{spec.flag[2:]}", dest=f.name, action="store_false",
                                   default=True, help=f"turn off what is on by default: {spec.help}")
            else:
                where.add_argument(spec.flag, dest=f.name, action="store_true", help=spec.help)
            continue
        names = [n for n in (spec.short, spec.flag) if n]
        shown = "" if default is None else f" (default {default})"
        where.add_argument(*names, dest=f.name, type=parse_value(f.name, spec), default=default,
                           metavar=spec.metavar or (None if spec.choices else f.name.upper()),
                           choices=spec.choices, help=spec.help.replace("%", "%%") + shown)


def options_from_args(args: argparse.Namespace, options: type[Options], *, skip: tuple[str, ...] = (),
                      **extra: Any) -> Options:
    """An instance of ``options`` from parsed arguments (options without a flag, and ``skip``,
    the ones :func:`add_flags` skipped, keep their defaults unless given in ``extra``)."""
    values = {name: getattr(args, name) for name in options.names()
              if hasattr(args, name) and name not in skip}
    values.update(extra)
    return options(**values)
