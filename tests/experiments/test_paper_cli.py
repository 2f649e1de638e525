"""``mlkm paper``: the exit status follows the checks; importing it leaves the environment."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from mlkm_experiments import paper


def _fake_run(checks):
    def run(n_datasets, out, jobs, dnn_datasets, segment_size):
        return {'checks': checks, 'wall_s': 1.0}

    return run


@pytest.mark.parametrize(
    ('checks', 'code'),
    [
        ([('a', True), ('b', True)], 0),
        ([('a', True), ('MLKM w/ EC mean in [85, 98] %', False)], 1),
    ],
)
def test_exit_status_follows_the_checks(monkeypatch, tmp_path, capsys, checks, code):
    from mlkm_assoc import cli

    monkeypatch.setattr(paper, 'run', _fake_run(checks))
    assert cli.main(['paper', '--datasets', '1', '--output', str(tmp_path)]) == code
    out = capsys.readouterr().out
    assert f'{sum(ok for _, ok in checks)}/{len(checks)} checks hold' in out
    if code:
        assert 'check does not hold: MLKM w/ EC mean in [85, 98] %' in out


def test_import_leaves_the_thread_variables_alone():
    env = {k: v for k, v in os.environ.items() if k not in paper.WORKER_THREADS}
    code = (
        'import os, mlkm_experiments.paper; '
        'print(sorted(v for v in mlkm_experiments.paper.WORKER_THREADS if v in os.environ))'
    )
    res = subprocess.run(
        [sys.executable, '-c', code], env=env, capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().splitlines()[-1] == '[]'


def test_one_thread_workers_sets_only_unset_variables_and_restores(monkeypatch):
    monkeypatch.delenv('OMP_NUM_THREADS', raising=False)
    monkeypatch.setenv('MKL_NUM_THREADS', '4')
    with paper.one_thread_workers():
        assert os.environ['OMP_NUM_THREADS'] == '1'
        assert os.environ['MKL_NUM_THREADS'] == '4'
    assert 'OMP_NUM_THREADS' not in os.environ
    assert os.environ['MKL_NUM_THREADS'] == '4'
