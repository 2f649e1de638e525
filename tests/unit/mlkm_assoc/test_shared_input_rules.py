"""The rules the association node and the offline CLI (``mlkm associate``) share: which
detections are one report received twice (``mlkm_core.types.duplicate_key``), and a road
[0, road_length] whose station may stand at its origin."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mlkm_assoc.assembly import Assembler, AssociationConfig
from mlkm_assoc.stream_ingest import StreamIngest
from mlkm_core.bounds import Bounds
from mlkm_core.csvio import read_detections
from mlkm_core.types import Layout
from mlkm_ros import conversions as conv

S = 1_000_000_000
IDS = [10, 11]
POS = [100.0, 200.0]
LAYOUT = Layout(400.0, np.array(POS), np.array(IDS), ('a', 'b'))
# (sensor index, lane, stamp [s], velocity [m/s]), in arrival order
ROWS = [
    (0, -1, 10.0, 30.0),
    (0, -1, 10.0, 25.0),  # lane unknown, another speed: a second vehicle
    (0, -1, 10.0, 30.0),  # the first report again: a duplicate
    (0, 1, 10.0, 30.0),  # a known lane is another report
    (0, 1, 10.0, 22.0),  # same sensor, lane and stamp: a duplicate
    (1, -1, 10.0, 30.0),  # another sensor
]


def _csv_duplicates(tmp_path) -> list[int]:
    path = tmp_path / 'rows.csv'
    lines = ['sensor_id,position_m,stamp_s,velocity_mps,lane']
    lines += [f'{IDS[s]},{POS[s]!r},{t!r},{v!r},{lane}' for s, lane, t, v in ROWS]
    path.write_text('\n'.join(lines) + '\n')
    data = read_detections(path, skip_invalid=True)
    assert data.layout.positions.tolist() == POS
    return sorted(k for k, p in data.problems.items() if p.reason == 'duplicate')


def _assembler_duplicates() -> list[int]:
    a = Assembler(AssociationConfig(segment_size=2), lambda job: None, lambda r, _: None)
    a.set_layout(LAYOUT, 0.0, 0, None)
    a.add_episode(0, 4, 0, 100 * S, None, 0.0, 1)
    out = []
    for k, (s, lane, t, v) in enumerate(ROWS):
        before = a.rejected['duplicate']
        a.add_detection(IDS[s], round(t * S), POS[s], v, 0.0, lane, math.nan)
        if a.rejected['duplicate'] > before:
            out.append(k)
    assert a.accepted + a.rejected['duplicate'] == len(ROWS)
    return out


def _stream_duplicates() -> list[int]:
    ingest = StreamIngest(Bounds(), 100, lambda item: None)
    ingest.set_layout(LAYOUT, None, (), ())
    out = []
    for k, (s, lane, t, v) in enumerate(ROWS):
        before = ingest.rejected['duplicate']
        ingest.add(IDS[s], round(t * S), POS[s], v, lane, math.nan, 0.0)
        if ingest.rejected['duplicate'] > before:
            out.append(k)
    assert ingest.accepted + ingest.rejected['duplicate'] == len(ROWS)
    return out


def test_node_and_cli_refuse_the_same_rows_as_duplicates(tmp_path) -> None:
    expected = [2, 4]
    assert _assembler_duplicates() == expected
    assert _stream_duplicates() == expected
    assert _csv_duplicates(tmp_path) == expected


def test_a_station_at_the_road_origin_is_a_valid_layout() -> None:
    msg = conv.layout_to_msg(LAYOUT, 5)
    msg.positions = [0.0, 200.0]
    assert conv.layout_from_msg(msg).positions.tolist() == [0.0, 200.0]
    msg.positions = [-1.0, 200.0]
    with pytest.raises(ValueError, match=r'\[0, road_length\]'):
        conv.layout_from_msg(msg)
