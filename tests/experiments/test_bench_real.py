"""``mlkm bench --only real``: the NGSIM part on one cell, its JSON, report and targets."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mlkm_experiments.bench import peer, real

DATA = Path(__file__).resolve().parents[2] / real.DATA


@pytest.mark.slow
def test_one_real_cell_end_to_end_through_the_cli(tmp_path, monkeypatch):
    from mlkm_assoc import cli

    monkeypatch.setattr(real, 'STATIONS', (10,))
    monkeypatch.setattr(real, 'VARIANTS_ROAD', ('closed',))
    monkeypatch.setattr(peer, 'stonesoup_version', lambda: None)  # the peer part tests it
    out = tmp_path / 'out'
    argv = ['bench', '--quick', '--only', 'real', '--methods', 'assignment,multiframe']
    assert cli.main([*argv, '--output', str(out), '--real-data', str(DATA)]) == 0

    data = json.loads((out / 'real.json').read_text())
    (cell,) = data['cells']
    assert (cell['stations'], cell['road']) == (10, 'closed')
    # 10 loops over 400 m from the first placement: every vehicle seen at all ten
    assert cell['detections_mean'] == 10 * cell['vehicles_mean']
    for variant in real.VARIANTS:
        runs = cell['variants'][variant]
        assert set(runs) == {'assignment', 'multiframe', real.STREAM}
        for rec in runs.values():
            (row,) = rec['runs']
            assert 0.0 <= row['accuracy'] <= 1.0 and row['degraded'] >= 0
    # with lane and length the tracking methods link every real vehicle of this cell
    assert cell['variants']['lane_length']['assignment']['summary']['accuracy_mean'] == 1.0
    readme = (out / 'README.md').read_text()
    assert '## Real traffic: NGSIM I-80' in readme
    targets = json.loads((out / 'summary.json').read_text())['targets']
    names = [t['target'] for t in targets if t['target'].startswith('real 10 stations closed')]
    assert 'real 10 stations closed: multiframe with lane and length = 100%' in names


def test_a_missing_data_file_leaves_the_part_not_run(tmp_path):
    out = real.run_real(['assignment'], 1, print, tmp_path / 'nowhere.csv.gz')
    assert out['status'].startswith('not run:')
    assert real.real_targets(out)[0]['met'] is None


def test_the_placements_are_drawn_inside_their_range():
    starts = [real.placement(s) for s in range(1, 20)]
    assert all(real.START[0] <= x <= real.START[1] for x in starts)
    assert len(set(starts)) == len(starts)
