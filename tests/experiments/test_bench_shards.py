"""``mlkm bench --only shards`` on a small input: real NGSIM traffic through 10 loops, where
one, two and four shards associate alike, and the part's report table."""

from __future__ import annotations

from pathlib import Path

import pytest

from mlkm_core.loops import even_positions, virtual_loops
from mlkm_core.trajectories import read_trajectories
from mlkm_experiments.bench import shards

pytestmark = pytest.mark.slow

DATA = Path(__file__).resolve().parents[2] / 'data' / 'ngsim_i80' / 'i80_trajectories_a.csv.gz'


def test_shards_part_compares_every_count_with_one_tracker() -> None:
    ds = virtual_loops(read_trajectories(DATA), even_positions(10, 50, 450), closed=False)
    lines: list[str] = []
    out = shards.compare('NGSIM 10 loops', ds.dataset.layout, ds.dataset.detections, lines.append)
    rows = out['rows']
    assert [r['shards'] for r in rows] == list(shards.COUNTS)
    assert rows[0]['accuracy'] > 0.99 and rows[0]['links_differing'] == 0
    for r in rows[1:]:
        assert len(r['continued']) == r['shards'] and r['continued'][0] == 0
        assert min(r['continued'][1:]) > 90  # about every vehicle crosses every border
        assert r['links_differing_at_a_border'] <= r['links_differing']
        # every border is crossed by about every vehicle; the hand-off carries those links
        # as one tracker makes them
        assert r['border_links'] > 90 * (r['shards'] - 1)
        assert r['border_right'] == r['border_right_one'] >= 0.99 * r['border_links']
    assert len(lines) == len(shards.COUNTS)
    table = shards.report_lines({'datasets': [out], 'method': 'multiframe', 'lag': 30.0})
    assert table[0] == '## Shards (`--only shards`)'
    assert sum(line.startswith('| NGSIM 10 loops |') for line in table) == len(shards.COUNTS)
