"""``mlkm bench --only sumo --families-only`` on one tiny family cell and one two-point curve."""

from __future__ import annotations

import json

import pytest

from mlkm_core.associators import AssociatorConfig, make_associator
from mlkm_core.metrics import score
from mlkm_experiments.bench import sumo, sumo_families
from mlkm_sumo.families import draw


@pytest.mark.slow
def test_a_family_cell_end_to_end_through_the_cli(tmp_path, monkeypatch):
    from mlkm_assoc import cli

    monkeypatch.setattr(sumo_families, 'FAMILY_CELLS', ('ramps',))
    monkeypatch.setattr(
        sumo_families, 'CURVES', (('severity', 'work_zone', 'severity', (0.6, 1.5)),)
    )
    monkeypatch.setitem(
        sumo_families.PLANS, 'quick', {'seeds': 1, 'curve_seeds': 1, 'peer_seeds': 0}
    )
    out = tmp_path / 'out'
    out.mkdir()
    # the cells of today's scenarios are kept from the part's last JSON
    (out / 'sumo.json').write_text(json.dumps({'cells': [], 'date': 'earlier', 'wall_s': 1.0}))
    argv = ['bench', '--quick', '--only', 'sumo', '--families-only', '--methods', 'assignment']
    assert cli.main([*argv, '--output', str(out), '--cache-dir', str(tmp_path / 'cache')]) == 0

    data = json.loads((out / 'sumo.json').read_text())
    assert data['cells_run']['date'] == 'earlier' and data['cells'] == []
    fam = data['families']
    assert [c['family'] for c in fam['cells']] == ['ramps']
    assert fam['families']['work_zone']['ranges']['severity'] == [0.8, 1.5]
    cell = fam['cells'][0]
    (recorded,) = cell['draws']
    # the draw is recorded and rebuilt from (family, seed)
    assert recorded == json.loads(json.dumps(draw('ramps', 1).to_json()))
    assert cell['seeds'] == [1] and cell['overrides'] == {}
    cache = sumo.DatasetCache(tmp_path / 'cache')
    path = cache.family(draw('ramps', 1))
    d = draw('ramps', 1)
    config = AssociatorConfig(entries=d.entries, exits=d.exits)
    assert d.entries and d.exits  # the ramps family has both
    for variant in ('time_speed', 'lane_length'):
        rec = cell['variants'][variant]['assignment']
        assert rec['status'] == 'ok' and rec['summary']['n'] == 1
        acc = rec['summary']['accuracy_mean']
        assert isinstance(acc, float) and 0.0 <= acc <= 1.0
        ds = sumo.load(path, variant)
        labels = make_associator('assignment', config).associate(
            ds.layout, ds.detections, ds.n_targets
        )
        assert rec['runs'][0]['accuracy'] == score(ds.detections, labels).accuracy
        assert 50 <= ds.n_targets <= 150 and rec['runs'][0]['detections'] == len(ds.detections)
    assert common_peer_absent(cell)
    # the curve: the severity fixed, the rest of the draw that of (family, seed)
    (cv,) = fam['curves']
    assert [p['x'] for p in cv['points']] == [0.6, 1.5]
    for p in cv['points']:
        (dr,) = p['draws']
        assert p['overrides'] == {'severity': p['x']} and dr['severity'] == p['x']
        assert dr == json.loads(json.dumps(draw('work_zone', 1, severity=p['x']).to_json()))
        acc = p['variants']['lane_length']['assignment']['summary']['accuracy_mean']
        assert 0.0 <= acc <= 1.0
    assert (out / 'sumo_curve_severity_work_zone.png').stat().st_size > 1000
    readme = (out / 'README.md').read_text()
    assert '## SUMO scenario families' in readme and '### Family `ramps`' in readme
    assert '### Accuracy against severity: `work_zone`' in readme
    assert '![severity work_zone](sumo_curve_severity_work_zone.png)' in readme
    targets = json.loads((out / 'summary.json').read_text())['targets']
    fam_targets = {t['target']: t for t in targets if t['target'].startswith('sumo families')}
    # multiframe did not run: its targets are not measured, not passed
    assert fam_targets and all(t['met'] is None for t in fam_targets.values())


def common_peer_absent(cell: dict) -> bool:
    return all(set(v) == {'assignment'} for v in cell['variants'].values())


def _cell(acc: dict[str, float], x: float | None = None) -> dict:
    """A cell whose best method has these mean accuracies per variant."""
    rec = lambda a: {'summary': {'n': 1, 'accuracy_mean': a, 'accuracy_min': a}}  # noqa: E731
    out = {'variants': {v: {'multiframe': rec(a)} for v, a in acc.items()}}
    return out if x is None else {'x': x, **out}


def test_family_targets_report_pass_fail_and_cliffs():
    from mlkm_experiments.bench.sumo_families_report import family_targets

    fam = {
        'cells': [
            {'family': 'free_flow', **_cell({'lane_length': 0.995, 'time_speed': 0.97})},
            {'family': 'ramps', **_cell({'lane_length': 0.96, 'time_speed': 0.9})},
            {'family': 'work_zone', **_cell({'lane_length': 0.97, 'time_speed': 0.86})},
        ],
        'curves': [
            {
                'name': 'severity',
                'family': 'work_zone',
                'parameter': 'severity',
                'points': [
                    _cell({'lane_length': 0.99, 'time_speed': 0.95}, 0.6),
                    _cell({'lane_length': 0.97, 'time_speed': 0.84}, 0.9),
                ],
            }
        ],
    }
    got = {t['target'].split(': ', 1)[1]: t for t in family_targets({'families': fam})}
    assert got['free_flow, with lane and length: mean >= 99%']['met'] is True
    assert got['ramps, with lane and length: mean >= 97%']['met'] is False
    ll = 'work zone, with lane and length: mean >= 95% at every severity (cell and curve)'
    ts = 'work zone, time and speed only: mean >= 85% at every severity (cell and curve)'
    assert got[ll]['met'] is True
    assert got[ts]['met'] is False and 'severity 0.9: 84.00%' in got[ts]['value']
    (cliff,) = [t for k, t in got.items() if k.startswith('no cliff')]
    assert cliff['met'] is False and cliff['value'] == 'time_speed 0.6 -> 0.9: -11.0 points'
    assert family_targets({}) == []


def test_a_second_families_only_run_keeps_the_date_of_the_cells_it_keeps(monkeypatch):
    """The cells of today's scenarios come from the run that made them, not from the
    families-only run before this one."""
    monkeypatch.setattr(sumo_families, 'run_families', lambda *args, **kwargs: {'cells': []})
    first = {'cells': [{'scenario': 'highway'}], 'date': 'cells made', 'wall_s': 9.0}
    once = sumo.run_sumo(['assignment'], {}, print, previous={**first, 'date': 'cells made'})
    assert once['cells_run']['date'] == 'cells made'
    twice = sumo.run_sumo(['assignment'], {}, print, previous={**once, 'date': 'families'})
    assert twice['cells_run']['date'] == 'cells made'
    assert twice['cells'] == [{'scenario': 'highway'}]
