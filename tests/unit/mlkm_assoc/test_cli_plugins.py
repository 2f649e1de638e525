"""``mlkm`` finds its further subcommands through the ``mlkm.commands`` entry points.

mlkm_assoc names no benchmark module: ``mlkm paper`` and ``mlkm bench`` come from
mlkm_experiments' entry points, ``mlkm sumo`` from mlkm_sumo's, ``mlkm loops`` and
``mlkm plot`` from mlkm_assoc's own.
"""

from __future__ import annotations

import importlib.metadata
import json
import re
import subprocess
import sys

import pytest

from mlkm_assoc import cli, cli_plugins


def _entry(name: str, value: str) -> importlib.metadata.EntryPoint:
    return importlib.metadata.EntryPoint(name, value, cli_plugins.COMMANDS_GROUP)


def echo(argv: list[str]) -> int:
    """echo the arguments

    More text that is not the help line."""
    print('echo got', argv)
    return 7


def test_installed_commands_are_listed_and_dispatched(capsys):
    names = set(cli.plugin_commands())
    assert {'paper', 'bench', 'sumo', 'loops', 'plot'} <= names, f'installed: {names}; make setup?'
    with pytest.raises(SystemExit) as exc:
        cli.main(['--help'])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    listed = re.search(r'\{([a-z,]+)\}', out).group(1).split(',')
    assert {'associate', 'bench', 'loops', 'paper', 'plot', 'sumo'} <= set(listed)
    assert listed == sorted(listed)
    assert "reproduce the paper's experiments" in out and 'benchmarks' in out
    with pytest.raises(SystemExit):
        cli.main(['paper', '--help'])
    assert 'usage: mlkm paper' in capsys.readouterr().out


def test_a_plugin_gets_the_arguments_after_its_name(monkeypatch, capsys):
    this = f'{__name__}:echo'
    monkeypatch.setattr(cli, 'plugin_commands', lambda: {'echo': _entry('echo', this)})
    assert cli.main(['echo', '--help', '-x', 'y']) == 7
    assert "echo got ['--help', '-x', 'y']" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        cli.main(['-h'])
    out = capsys.readouterr().out
    assert 'echo the arguments' in out and 'More text' not in out


def test_a_broken_plugin_does_not_break_the_help(monkeypatch, capsys):
    broken = _entry('broken', 'no_such_module_xyz:main')
    monkeypatch.setattr(cli, 'plugin_commands', lambda: {'broken': broken})
    with pytest.raises(SystemExit):
        cli.main(['--help'])
    assert 'cannot be loaded: ModuleNotFoundError' in capsys.readouterr().out


def test_associate_cannot_be_replaced(monkeypatch):
    fake = [_entry('associate', f'{__name__}:echo'), _entry('echo', f'{__name__}:echo')]
    monkeypatch.setattr(importlib.metadata, 'entry_points', lambda group: fake)
    assert set(cli.plugin_commands()) == {'echo'}


def test_the_help_loads_no_experiment():
    code = (
        'import json, sys; from mlkm_assoc import cli; cli.build_parser(); '
        "print(json.dumps(sorted(m for m in sys.modules if m.startswith('mlkm_experiments'))))"
    )
    out = subprocess.run(
        [sys.executable, '-c', code], capture_output=True, text=True, timeout=120, check=True
    ).stdout
    # the help line of each plugin comes from its function: only the small
    # mlkm_experiments.commands is loaded, never the experiments themselves
    loaded = json.loads(out.strip().splitlines()[-1])
    assert set(loaded) <= {'mlkm_experiments', 'mlkm_experiments.commands'}, loaded
