"""docs/foxglove/mlkm_layout.json: a Foxglove layout whose panels show the graph's topics."""

from __future__ import annotations

import json
from pathlib import Path

LAYOUT = Path(__file__).resolve().parents[3] / 'docs' / 'foxglove' / 'mlkm_layout.json'


def _leaves(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert set(node) >= {'direction', 'first', 'second'}, node
    assert node['direction'] in ('row', 'column')
    return _leaves(node['first']) + _leaves(node['second'])


def test_layout_tree_and_panels() -> None:
    layout = json.loads(LAYOUT.read_text())
    panels = layout['configById']
    assert sorted(_leaves(layout['layout'])) == sorted(panels)  # every panel placed, once
    by_type = {panel_id.split('!')[0]: config for panel_id, config in panels.items()}
    assert set(by_type) == {'3D', 'Plot', 'RawMessages', 'DiagnosticSummary'}
    # the 3D panel shows the markers in their own frame: no transform needed
    assert by_type['3D']['followTf'] == 'road'
    assert by_type['3D']['topics'] == {'/mlkm/markers': {'visible': True}}
    assert [p['value'] for p in by_type['Plot']['paths']] == [
        '/mlkm/score.accuracy',
        '/mlkm/score.mean_accuracy',
    ]
    assert by_type['RawMessages']['topicPath'] == '/mlkm/tracks'
    assert by_type['DiagnosticSummary']['topicToRender'] == '/diagnostics'
