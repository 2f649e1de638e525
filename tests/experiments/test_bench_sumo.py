"""``mlkm bench --quick --only sumo`` on tiny SUMO datasets, and the budgeted child runner."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from mlkm_core.associators import AssociatorConfig, make_associator
from mlkm_core.metrics import score
from mlkm_experiments.bench import common, sumo, sumo_families


def test_time_speed_variant_strips_lane_and_length(tmp_path):
    path = sumo.DatasetCache(tmp_path).get('highway', 5, 3, 1)
    plain, full = sumo.load(path, 'time_speed'), sumo.load(path, 'lane_length')
    assert plain.detections.lane is None and plain.detections.length is None
    assert full.detections.lane is not None and full.detections.length is not None
    assert np.all(full.detections.length[full.detections.target >= 0] > 0)
    np.testing.assert_array_equal(plain.detections.stamp, full.detections.stamp)
    np.testing.assert_array_equal(plain.detections.target, full.detections.target)
    # the second request is served from the cache, not generated again
    mtime = path.stat().st_mtime_ns
    assert sumo.DatasetCache(tmp_path).get('highway', 5, 3, 1) == path
    assert path.stat().st_mtime_ns == mtime


@pytest.mark.slow
def test_quick_sumo_part_through_the_cli(tmp_path, monkeypatch):
    from mlkm_assoc import cli

    monkeypatch.setattr(sumo, 'SEEDS_QUICK', {(5, 3): 1})
    monkeypatch.setattr(sumo_families, 'plan', lambda quick: None)  # their own test
    monkeypatch.setattr(sumo, 'EXTRA_QUICK', {('ramps', 'clutter', (5, 3)): 1})
    monkeypatch.setitem(sumo.BUDGET, (5, 3), 120.0)
    monkeypatch.chdir(tmp_path)  # the default --output is results/bench under the cwd
    argv = ['bench', '--quick', '--only', 'sumo', '--methods', 'assignment']
    assert cli.main([*argv, '--cache-dir', str(tmp_path / 'cache')]) == 0

    out = tmp_path / 'results' / 'bench'
    data = json.loads((out / 'sumo.json').read_text())
    names = [(c['scenario'], c['measurement']) for c in data['cells']]
    assert names == [(s, 'default') for s in sumo.SCENARIOS] + [('ramps', 'clutter')]
    for c in data['cells']:
        # the road's ramps reach the associators: ramps has two on- and two off-ramps
        ramps = c['scenario'] == 'ramps'
        assert (len(c['entries']), len(c['exits'])) == ((2, 2) if ramps else (0, 0))
        assert (c['vehicles'], c['stations'], c['seeds']) == (5, 3, [1])
        plain, full = c['variants']['time_speed'], c['variants']['lane_length']
        assert set(plain) == {'assignment', common.PEER} and set(full) == {'assignment'}
        for rec in (plain['assignment'], full['assignment'], plain[common.PEER]):
            assert rec['status'] == 'ok' and rec['summary']['n'] == 1
            assert 0.0 <= rec['summary']['accuracy_mean'] <= 1.0
        # the figures are those of the method on the cached dataset, variant by variant
        path = sumo.DatasetCache(tmp_path / 'cache').path(c['scenario'], 5, 3, 1, c['measurement'])
        config = AssociatorConfig(entries=c['entries'], exits=c['exits'])
        for variant, rec in (('time_speed', plain), ('lane_length', full)):
            ds = sumo.load(path, variant)
            labels = make_associator('assignment', config).associate(
                ds.layout, ds.detections, ds.n_targets
            )
            assert (
                rec['assignment']['runs'][0]['accuracy'] == score(ds.detections, labels).accuracy
            )
            assert rec['assignment']['runs'][0]['detections'] == len(ds.detections) > 0
    readme = (out / 'README.md').read_text()
    assert '## SUMO traffic' in readme and '### 5 vehicles, 3 stations' in readme
    assert '| single_lane |' in readme and '`stonesoup`' in readme
    assert '| ramps (clutter) |' in readme
    assert 'same (time and speed only)' in readme
    assert not (out / 'grid.json').exists()  # only the part asked for ran


@pytest.mark.slow
def test_the_peer_runs_on_the_first_dataset_of_the_chosen_large_cells(tmp_path, monkeypatch):
    cell = (5, 3)
    monkeypatch.setitem(sumo.BUDGET, cell, 120.0)
    monkeypatch.setitem(sumo.LARGE_METHODS, cell, ('assignment',))
    monkeypatch.setattr(sumo, 'PEER_LARGE', {('highway', 'default', cell): 1})
    out = sumo.run_sumo(['assignment'], {cell: 2}, lambda msg: None, tmp_path, extra={})
    assert out['peer_budget_s'] == {'5x3': 120.0}  # no budget of its own: the methods'
    for c in out['cells']:
        plain = c['variants']['time_speed']
        assert plain['assignment']['summary']['n'] == 2
        if c['scenario'] != 'highway':
            assert set(plain) == {'assignment'}
            continue
        peer = plain[common.PEER]
        assert peer['datasets'] == 1 and peer['summary']['n'] == 1 and peer['status'] == 'ok'
        assert c['variants']['lane_length'].keys() == {'assignment'}
    text = '\n'.join(sumo.report_lines(out))
    assert '(dataset 1 of 2)' in text


def test_kept_peer_rows_are_not_run_again_and_say_when_they_ran(tmp_path, monkeypatch):
    """--keep-peer: the peer's row of a cell comes from the last sumo.json (the date of the run
    that made its cells), the methods run again, and the report says so."""
    cell = (5, 3)
    monkeypatch.setitem(sumo.BUDGET, cell, 120.0)
    monkeypatch.setitem(sumo.LARGE_METHODS, cell, ('assignment',))
    monkeypatch.setattr(sumo, 'PEER_LARGE', {('highway', 'default', cell): 1})
    run = {'accuracy': 0.5, 'link_precision': 0.5, 'link_recall': 0.5, 'identity_switches': 1,
           'adjusted_rand_index': 0.5, 'seconds': 9.0, 'detections': 15}  # fmt: skip
    row = {'summary': common.summarise([run]), 'status': 'ok', 'runs': [run], 'datasets': 1}
    previous = {
        'date': '2026-11-27 12:07 UTC',
        'cells_run': {'date': '2026-11-26 04:28 UTC'},
        'cells': [
            {'scenario': 'highway', 'vehicles': 5, 'stations': 3,
             'variants': {'time_speed': {common.PEER: row}}},
        ],
    }  # fmt: skip
    kept = sumo.peer_rows(previous)
    assert kept == {('highway', 'default', 5, 3): {**row, 'ran': '2026-11-26 04:28 UTC'}}
    ran = []
    monkeypatch.setattr(sumo, 'run_budgeted', lambda job, n, budget: ran.append(n) or ([], 'ok'))
    out = sumo.run_sumo(
        ['assignment'], {cell: 1}, lambda msg: None, tmp_path, extra={}, peer_rows=kept
    )
    highway = next(c for c in out['cells'] if c['scenario'] == 'highway')
    assert highway['variants']['time_speed'][common.PEER] == kept[('highway', 'default', 5, 3)]
    assert len(ran) == 2 * len(sumo.SCENARIOS)  # assignment, both variants: no peer run
    text = '\n'.join(sumo.report_lines(out))
    assert 'rows were kept from the run of 2026-11-26 04:28 UTC' in text


def _sleepy_job():
    def job(k: int) -> dict:
        time.sleep(0.1 if k == 0 else 30.0)
        return {'k': k}

    return job


def test_budget_stops_a_slow_method_and_says_after_how_many_datasets():
    t0 = time.monotonic()
    rows, status = common.run_budgeted(_sleepy_job, 3, budget=2.0)
    assert rows == [{'k': 0}]
    assert status == 'stopped at the 2 s time limit after 1 of 3 datasets'
    assert time.monotonic() - t0 < 25.0  # the child was killed, not waited for


def test_budgeted_run_reports_a_crashing_child():
    def make_job():
        def job(k: int) -> dict:
            if k == 1:
                raise SystemExit(3)
            return {'k': k}

        return job

    rows, status = common.run_budgeted(make_job, 3, budget=60.0)
    assert rows == [{'k': 0}]
    assert status.startswith('crashed after 1 datasets')


def test_a_failing_part_is_reported_and_fails_the_run(tmp_path, monkeypatch):
    from mlkm_experiments import bench

    def broken(*args, **kwargs):
        raise RuntimeError('netconvert missing')

    monkeypatch.setattr(sumo, 'run_sumo', broken)
    assert bench.main(['--only', 'sumo', '--output', str(tmp_path)]) == 1
    data = json.loads((tmp_path / 'sumo.json').read_text())
    assert data['status'] == 'failed: RuntimeError: netconvert missing'
    readme = (tmp_path / 'README.md').read_text()
    assert '## SUMO traffic\n\nfailed: RuntimeError: netconvert missing' in readme
