"""SUMO scenarios: networks build from their sources; short runs give sound detections.

Runs are short (tens of vehicles, a few stations) to stay cheap on a busy machine.
"""

import re
import shutil
from collections import Counter, defaultdict

import numpy as np
import pytest

from mlkm_sumo import SCENARIOS, MeasurementConfig, SumoError, episodes, generate, make_road
from mlkm_sumo.measurement import DOUBLE_REPORT, PASSAGE
from mlkm_sumo.network import build_network, scenario_files, scenarios_root
from mlkm_sumo.runner import SumoRun

VEHICLE_LENGTHS = {4.0, 4.6, 5.1, 6.5, 12.0, 16.5}  # scenarios/common/vtypes.add.xml


@pytest.fixture(scope='module')
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp('sumo_cache')


@pytest.mark.parametrize('name', list(SCENARIOS))
def test_network_builds_from_sources_into_an_empty_cache(name, tmp_path):
    net = build_network(scenario_files(name), tmp_path)
    assert net.is_file() and net.parent.parent == tmp_path
    assert re.fullmatch(rf'{name}-[0-9a-f]{{16}}', net.parent.name)
    text = net.read_text()
    assert '<net ' in text and 'id="m0"' in text
    mtime = net.stat().st_mtime_ns
    assert build_network(scenario_files(name), tmp_path) == net  # reused, not rebuilt
    assert net.stat().st_mtime_ns == mtime
    assert [p.name for p in tmp_path.iterdir()] == [net.parent.name]  # no leftovers


def test_netconvert_failure_is_a_clear_error(tmp_path, monkeypatch):
    src = tmp_path / 'scenarios'
    shutil.copytree(scenarios_root(), src)
    edges = src / 'highway' / 'highway.edg.xml'
    edges.write_text(edges.read_text().replace('to="end"', 'to="nowhere"'))
    monkeypatch.setenv('MLKM_SUMO_SCENARIOS', str(src))
    with pytest.raises(SumoError, match=r"netconvert failed for scenario 'highway'.*nowhere"):
        build_network(scenario_files('highway'), tmp_path / 'cache')
    assert not list((tmp_path / 'cache').iterdir())  # no partial network left behind


def test_bad_scenario_and_layout_are_clear_errors(cache):
    with pytest.raises(SumoError, match="unknown scenario 'motorway'.*highway"):
        generate('motorway', n_vehicles=5, cache_dir=cache)
    with pytest.raises(SumoError, match='1500 m lies in a junction'):
        make_road('ramps', stations_at=[1000, 1500], cache_dir=cache)
    with pytest.raises(SumoError, match='outside the usable road'):
        make_road('highway', stations_at=[50, 1000], cache_dir=cache)


def check_detections(ds, n_inserted):
    """Invariants of every scenario's run without measurement effects."""
    d, road = ds.detections, ds.road
    assert len(d) > 0 and d.lane is not None and d.length is not None
    assert np.all(np.diff(d.stamp) >= 0)
    # lanes and lengths within range
    assert np.all(d.lane >= 0) and np.all(d.lane < road.lanes[d.sensor_index])
    assert set(np.unique(d.length)) <= VEHICLE_LENGTHS
    assert np.all(d.velocity > 0) and np.all(d.velocity < 60)
    first = ds.kind == PASSAGE
    assert np.all(d.target[first] >= 0) and np.all(d.target[~first] == -1)
    assert np.all(ds.kind[~first] == DOUBLE_REPORT)
    # ground truth: targets are the SUMO vehicles v<k> that were inserted
    assert len(ds.vehicle_ids) == ds.n_targets == np.unique(d.target[first]).size
    assert all(re.fullmatch(r'v\d+', v) and int(v[1:]) < n_inserted for v in ds.vehicle_ids)
    per_vehicle = defaultdict(list)
    for k in np.flatnonzero(first):
        per_vehicle[int(d.target[k])].append(k)
    for t, ks in per_vehicle.items():
        stations = d.sensor_index[ks]
        # one detection per vehicle per station, times increasing along the road
        assert np.unique(stations).size == len(ks), ds.vehicle_ids[t]
        order = np.argsort(stations)
        assert np.all(np.diff(d.stamp[ks][order]) > 0), ds.vehicle_ids[t]
        # vehicles only appear on, and disappear from, the road at a ramp (or its ends)
        gaps = np.flatnonzero(np.diff(np.sort(stations)) > 1)
        assert not gaps.size, f'{ds.vehicle_ids[t]} skipped a station'
    return per_vehicle


@pytest.mark.parametrize('name', list(SCENARIOS))
def test_short_run_yields_sound_detections(name, cache):
    ds = generate(name, n_vehicles=60, n_stations=8, seed=3, cache_dir=cache)
    assert ds.stats['vehicles_inserted'] == 60 and ds.stats['in_network'] == 0
    per_vehicle = check_detections(ds, 60)
    n_st = ds.layout.n_sensors
    counts = Counter(len(ks) for ks in per_vehicle.values())
    if name == 'ramps':
        first_last = [
            (ds.detections.sensor_index[ks].min(), ds.detections.sensor_index[ks].max())
            for ks in per_vehicle.values()
        ]
        for lo, hi in first_last:  # a vehicle enters after / leaves before a station only
            assert lo == 0 or ds.road.enter_between[lo - 1], (lo, hi)  # at a ramp
            assert hi == n_st - 1 or ds.road.leave_between[hi], (lo, hi)
        assert counts[n_st] < len(per_vehicle), 'some vehicles enter or leave between stations'
    else:  # a closed road: every vehicle passes every station once
        assert counts == {n_st: 60}
        assert np.all(ds.road.lanes == ds.road.lanes.max()) or name == 'congested'


def test_ramps_layout_reports_lanes_and_openings(cache):
    road = make_road('ramps', stations_at=[600, 1300, 1800, 2150, 2600, 4700], cache_dir=cache)
    assert road.lanes.tolist() == [3, 4, 3, 4, 3, 3]  # acceleration/deceleration lanes
    assert road.enter_between.tolist() == [True, False, False, False, True]
    assert road.leave_between.tolist() == [False, False, False, True, True]
    assert road.loops[1] == ('m1_0', 'm1_1', 'm1_2', 'm1_3')
    congested = make_road('congested', stations_at=[3000, 3800], cache_dir=cache)
    assert congested.lanes.tolist() == [3, 1]


def test_loop_passages_equal_sumos_instant_loop_records(cache, tmp_path):
    """The passages read in process are SUMO's instantInductionLoop records (time, speed,
    length, vehicle, lane), double reports included."""
    road = make_road('ramps', stations_at=[250, 565, 1171, 1660, 2366], cache_dir=cache)
    out = tmp_path / 'instant.xml'
    with SumoRun(road, seed=1, step_length=0.2, instant_output=out) as run:
        run.add_demand(3000.0, n_vehicles=100)
        parts = []
        while run.pending:
            parts.append(run.step())
    ours = {}
    for p in parts:
        for k in range(len(p)):
            key = (int(p.station[k]), int(p.lane[k]), p.vehicle[k])
            ours.setdefault(key, []).append((p.time[k], p.speed[k], p.length[k]))
    theirs = {}
    pattern = (
        r'<instantOut id="is(\d+)_l(\d+)" time="([\d.]+)" state="enter" vehID="([^"]+)" '
        r'speed="([\d.]+)" length="([\d.]+)"'
    )
    for m in re.finditer(pattern, out.read_text()):
        key = (int(m.group(1)), int(m.group(2)), m.group(4))
        theirs.setdefault(key, []).append(tuple(float(m.group(i)) for i in (3, 5, 6)))
    assert len(theirs) > 300
    assert sum(p.kind.tolist().count(DOUBLE_REPORT) for p in parts) >= 5  # lane changes on loops
    assert ours.keys() == theirs.keys()
    for key, got in ours.items():
        want = theirs[key]
        assert len(got) == len(want), key
        for (t, v, length), (t2, v2, length2) in zip(got, want):
            assert t == pytest.approx(t2, abs=0.006), key  # SUMO prints 2 decimals
            assert v == pytest.approx(v2, abs=0.006) and length == pytest.approx(length2), key


def test_measurement_rates_on_a_sumo_run(cache):
    cfg = MeasurementConfig(miss_rate=0.2, false_alarm_rate=360.0, double_reports=False)
    ds = generate('highway', n_vehicles=60, n_stations=8, seed=3, measurement=cfg, cache_dir=cache)
    s = ds.stats
    assert s['passages'] == 480 and s['double_reports_removed'] == s['double_reports']
    assert abs(s['missed'] - 96) < 5 * np.sqrt(480 * 0.2 * 0.8)
    expected_fa = 360.0 * 8 * s['simulated_s'] / 3600
    assert abs(s['false_alarms'] - expected_fa) < 5 * np.sqrt(expected_fa)
    assert len(ds.detections) == 480 - s['missed'] + s['false_alarms']
    assert np.sum(ds.detections.target == -1) == s['false_alarms']


def test_episodes_release_batches_that_all_leave(cache):
    eps = episodes('single_lane', n_vehicles=15, n_episodes=2, n_stations=4, seed=2,
                   cache_dir=cache)  # fmt: skip
    first, second = list(eps)
    for ep in (first, second):
        assert ep.n_targets == 15 and len(ep.detections) == 15 * 4
        assert ep.stats['vehicles_arrived'] == 15 and ep.stats['in_network'] == 0
    assert second.detections.stamp.min() > first.detections.stamp.max()
    assert set(first.vehicle_ids).isdisjoint(second.vehicle_ids)


@pytest.mark.slow
def test_congested_queues_upstream_of_the_road_works(cache):
    kw = {'n_vehicles': 300, 'stations_at': [3300, 4500], 'seed': 1, 'cache_dir': cache}
    jam, free = generate('congested', **kw), generate('highway', **kw)
    for ds in (jam, free):
        assert ds.n_targets == 300 and ds.stats['teleports'] == 0
    v = {
        name: [ds.detections.velocity[ds.detections.sensor_index == i] for i in (0, 1)]
        for name, ds in (('jam', jam), ('free', free))
    }
    assert np.percentile(v['jam'][0], 5) < 8.0  # stop-and-go before the works
    assert np.median(v['jam'][0]) < 0.6 * np.median(v['free'][0])
    assert np.percentile(v['jam'][1], 5) > 20.0  # free flow again after them
