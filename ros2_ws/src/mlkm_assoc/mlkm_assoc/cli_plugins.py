"""The subcommands other packages add to ``mlkm`` (entry points of ``COMMANDS_GROUP``; the
contract is in ``mlkm_assoc.cli``'s docstring) and the one-line form of a warning that any
subcommand raises."""

from __future__ import annotations

import sys

__all__ = ['BUILTIN', 'COMMANDS_GROUP', 'one_line_warnings', 'plugin_commands', 'plugin_help']

#: Entry-point group of the subcommands other packages add to ``mlkm`` (see the docstring).
COMMANDS_GROUP = 'mlkm.commands'
BUILTIN = ('associate',)


def plugin_commands() -> dict:
    """``{name: importlib.metadata.EntryPoint}`` of the installed ``mlkm.commands``."""
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=COMMANDS_GROUP) if ep.name not in BUILTIN}


def plugin_help(entry) -> str:
    try:
        func = entry.load()
    except Exception as exc:  # a broken plugin must not break `mlkm --help`
        return f'(cannot be loaded: {type(exc).__name__}: {exc})'
    doc = func.__doc__ or getattr(sys.modules.get(func.__module__), '__doc__', None) or ''
    line = doc.strip().split('\n')[0].strip().rstrip('.')
    # a module docstring's ``mlkm sumo``: prefix repeats the name
    return line.split(': ', 1)[1] if line.startswith(f'``mlkm {entry.name}``: ') else line


def one_line_warnings(prog: str):
    """A ``warnings.showwarning`` that prints ``<prog>: warning: <message>`` as one line on
    stderr: what went wrong, not where in the installed sources."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        text = ' '.join(str(message).split())
        kind = '' if issubclass(category, UserWarning) else f'{category.__name__}: '
        try:
            print(f'{prog}: warning: {kind}{text}', file=file or sys.stderr)
        except OSError:  # stderr closed: a warning must not fail the command
            pass

    return show
