"""Argument types and shared options of the ``mlkm`` subcommands (of every package, hence
here in the core): a bad value is argparse's one-line usage error naming the flag, the value
and what is expected.

Every subcommand names the same thing the same way: ``--output`` is what it writes (a file
or a directory), ``--layout`` the road as a layout file, ``--seed`` a seed in [0, 2^32 - 1].
A spelling a subcommand used before stays accepted as a hidden alias (``renamed_option``)
that prints one note naming the new one, so that scripts keep working.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable


def positive_int(text: str) -> int:
    """An integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not an integer: {text!r}') from None
    if value < 1:
        raise argparse.ArgumentTypeError(f'must be >= 1, got {value}')
    return value


def finite_float(text: str) -> float:
    """A finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}') from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be finite, got {text!r}')
    return value


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f'must be > 0, got {text!r}')
    return value


def non_negative_float(text: str) -> float:
    """A finite number >= 0."""
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f'must be >= 0, got {text!r}')
    return value


def probability(text: str) -> float:
    """A probability in [0, 1)."""
    value = finite_float(text)
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f'must be in [0, 1), got {text!r}')
    return value


def seed(text: str) -> int:
    """A seed in [0, 2^32 - 1] (numpy's SeedSequence and scikit-learn accept it)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not an integer: {text!r}') from None
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError('must be in [0, 2^32 - 1]')
    return value


class _RenamedAlias(argparse.Action):
    """The old spelling of an option: stores like the new one and prints one note."""

    def __init__(self, option_strings, dest, new: str = '', **kwargs) -> None:
        self.new = new
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(
            f'{parser.prog}: note: {option_string} is deprecated; use {self.new}',
            file=sys.stderr,
        )
        setattr(namespace, self.dest, values)


def renamed_option(
    parser, new: str, old: str, required: bool = False, group=None, **kwargs
) -> None:
    """Add option ``new`` (``add_argument``'s ``kwargs``) with ``old`` as a hidden alias.

    ``required``: one of the two must be given; the usage and the error name only ``new``.
    ``group``: a mutually exclusive group of the parser to add both to (else a new one)."""
    if group is None:
        group = parser.add_mutually_exclusive_group(required=required)
    action = group.add_argument(new, **kwargs)
    group.add_argument(
        old,
        dest=action.dest,
        action=_RenamedAlias,
        new=new,
        type=action.type,
        metavar=action.metavar,
        help=argparse.SUPPRESS,
    )


class Refused(Exception):
    """A subcommand refuses its input or arguments (``refusing`` prints it as one line)."""


class RefusingParser(argparse.ArgumentParser):
    """argparse that reports a usage error as the subcommand's one-line error (``Refused``:
    exit 2 through ``refusing``)."""

    def error(self, message: str):
        raise Refused(message)


def refusing(prog: str, run: Callable[[list[str]], int], argv: list[str] | None) -> int:
    """``run(argv)`` (``sys.argv[1:]`` when None); a ``Refused`` becomes one line
    ``PROG: error: ...`` on stderr and exit status 2, with nothing written."""
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        return run(args)
    except Refused as exc:
        print(f'{prog}: error: {exc}', file=sys.stderr)
        return 2
