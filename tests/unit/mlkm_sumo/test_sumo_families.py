"""Scenario families: the draw is a pure function of (family, seed), stays inside the
family's ranges, and its sources build into the road it describes."""

import json

import numpy as np
import pytest

from mlkm_sumo import SumoError, make_road
from mlkm_sumo.families import (
    CAPACITY_PER_LANE,
    CAR_LENGTH,
    END_MARGIN,
    FAMILIES,
    NODE_MARGIN,
    TRUCK_LENGTH,
    TWO_TYPE,
    VAN_LENGTH,
    draw,
)
from mlkm_sumo.family_sources import draw_key, write_sources

SEEDS = range(1, 31)


def _inside(value, lo_hi):
    lo, hi = lo_hi
    return lo <= value <= hi


@pytest.mark.parametrize('name', list(FAMILIES))
def test_the_draw_is_a_pure_function_of_family_and_seed(name):
    a = draw(name, 7).to_json()
    b = draw(name, 7).to_json()
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    assert draw(name, 8).to_json() != a
    # drawing other things in between changes nothing
    for other in FAMILIES:
        draw(other, 7)
    assert draw(name, 7).to_json() == a
    assert draw_key(draw(name, 7)) == draw_key(draw(name, 7)) != draw_key(draw(name, 8))


@pytest.mark.parametrize('name', list(FAMILIES))
def test_every_draw_stays_inside_the_family_ranges(name):
    f = FAMILIES[name]
    for seed in SEEDS:
        d = draw(name, seed)
        assert d.family == name and d.seed == seed and d.overrides == {}
        assert _inside(d.lanes, f.range('lanes'))
        assert _inside(d.road_length, f.range('road_length'))
        assert _inside(d.speed_limit, f.range('speed_limit'))
        assert _inside(d.severity, f.range('severity'))
        assert _inside(d.vehicles, f.range('vehicles'))
        assert _inside(d.spacing, f.range('spacing'))
        assert _inside(d.jitter, f.range('jitter'))
        assert d.mix in f.range('mix')
        # the mainline covers the road without gaps
        segs = d.segments
        assert segs[0]['start'] == 0.0 and segs[-1]['end'] == d.road_length
        assert all(a['end'] == b['start'] for a, b in zip(segs, segs[1:]))
        assert len(d.links) == len(segs) - 1
        # severity = flow over the bottleneck's capacity (on its most loaded section)
        assert d.capacity == d.bottleneck['lanes'] * CAPACITY_PER_LANE
        assert d.flow >= d.severity * d.capacity - 0.1
        assert sum(r['probability'] for r in d.routes) == pytest.approx(1.0, abs=1e-3)
        # stations: inside the road, in order, spaced by the drawn spacing and jitter
        x = np.array(d.stations)
        assert x.size >= 2 and np.all(np.diff(x) > 0)
        assert x[0] >= END_MARGIN and x[-1] <= d.road_length - END_MARGIN
        gaps = np.diff(x)
        # (a station moved off a junction moves by up to NODE_MARGIN)
        assert np.all(gaps <= d.spacing * (1 + 2 * d.jitter) + 2 * NODE_MARGIN)
        nodes = [s['start'] for s in segs[1:]]
        assert all(abs(a - n) >= NODE_MARGIN - 0.05 for a in x for n in nodes)
        assert np.median(gaps) == pytest.approx(d.spacing, rel=2 * d.jitter + 0.02)
        # vehicle types: the two-type mix, or cars / vans / trucks spread in their ranges
        assert sum(t['share'] for t in d.vtypes) == pytest.approx(1.0, abs=1e-3)
        for t in d.vtypes:
            if d.mix == 'two_type':
                assert t['length'] == TWO_TYPE[t['cls']]
            else:
                lo_hi = {'car': CAR_LENGTH[2], 'van': VAN_LENGTH, 'truck': TRUCK_LENGTH}
                assert _inside(t['length'], lo_hi[t['cls']])
        truck = sum(t['share'] for t in d.vtypes if t['cls'] == 'truck')
        assert _inside(round(truck, 3), f.range('truck_share'))
        b = d.bottleneck
        if name == 'work_zone':
            assert 300.0 <= b['end'] - b['start'] <= 900.0 and b['lanes'] == 1
            assert [s['lanes'] for s in segs] == [d.lanes, 1, d.lanes]
        elif name == 'lane_drop':
            assert [s['lanes'] for s in segs] == [d.lanes, d.lanes - 1]
        elif name == 'ramps':
            kinds = {r['kind'] for r in d.ramps}
            assert kinds == {'on', 'off'} and _inside(len(d.ramps), f.range('ramps'))
            gaps = np.diff([r['position'] for r in d.ramps])
            assert np.allclose(gaps, gaps[0], atol=0.2)
            assert _inside(gaps[0], f.range('ramp_spacing'))
            assert _inside(b['ramp_share'], f.range('ramp_share'))
        else:
            assert len(segs) == 1 and not d.ramps and d.severity < 0.6


def test_the_draws_spread_over_the_ranges():
    ds = [draw('work_zone', s) for s in SEEDS]
    assert {d.lanes for d in ds} == {2, 3, 4}
    assert {d.mix for d in ds} == {'continuous', 'two_type'}
    sev = [d.severity for d in ds]
    assert min(sev) < 0.95 and max(sev) > 1.35


def test_overrides_fix_one_parameter_and_keep_the_rest_of_the_draw():
    base = draw('work_zone', 3).to_json()
    wide = draw('work_zone', 3, spacing=1000.0).to_json()
    dense = draw('work_zone', 3, severity=1.5).to_json()
    assert wide['spacing'] == 1000.0 and wide['overrides'] == {'spacing': 1000.0}
    assert dense['severity'] == 1.5 and dense['flow'] == pytest.approx(1.5 * 2 * 1000.0 * 1.0)
    for key in ('lanes', 'road_length', 'segments', 'vtypes', 'vehicles', 'routes'):
        assert wide[key] == base[key] == dense[key]
    assert dense['stations'] == base['stations'] and wide['stations'] != base['stations']
    with pytest.raises(SumoError, match='cannot override lanes'):
        draw('work_zone', 3, lanes=2)
    with pytest.raises(SumoError, match="unknown family 'motorway'"):
        draw('motorway', 1)


@pytest.mark.parametrize('name', list(FAMILIES))
def test_the_sources_build_into_the_drawn_road(name, tmp_path):
    d = draw(name, 2)
    files = write_sources(d, tmp_path)
    assert write_sources(d, tmp_path) == files  # written once, same place
    assert json.loads((files.nodes.parent / 'draw.json').read_text()) == d.to_json()
    road = make_road(name, stations_at=d.stations, cache_dir=tmp_path, files=files)
    assert road.files == files
    assert road.layout.road_length == pytest.approx(d.road_length)
    np.testing.assert_allclose(road.layout.positions, d.stations)
    for x, lanes in zip(d.stations, road.lanes):
        seg = next(s for s in d.segments if s['start'] <= x <= s['end'])
        assert lanes == seg['lanes']
    assert sorted(r.position for r in road.ramps if r.kind == 'on') == pytest.approx(
        sorted(d.entries)
    )
    assert sorted(r.position for r in road.ramps if r.kind == 'off') == pytest.approx(
        sorted(d.exits)
    )
