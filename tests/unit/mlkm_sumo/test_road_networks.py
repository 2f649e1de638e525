"""Road-network families: the draw is a pure function of (family, seed) inside the family's
ranges, and a seeded run gives detections that agree with the network it reports: every
detection on its vehicle's route, every vehicle's stations in an order the connections allow,
vehicles that turn, and (on the arterial) vehicles held at red lights."""

import csv
import json
from collections import deque
from xml.etree import ElementTree

import numpy as np
import pytest
import yaml

from mlkm_sumo import MeasurementConfig, SumoError
from mlkm_sumo.measurement import FALSE_ALARM as FALSE_ALARM_KIND
from mlkm_sumo.measurement import PASSAGE
from mlkm_sumo.network_sources import build_draw
from mlkm_sumo.road_networks import (
    NETWORK_FAMILIES,
    draw_network,
    generate_network,
    network_stream,
    write_network_dataset,
)

FAMILIES = list(NETWORK_FAMILIES)
#: Vehicles of the test runs (a third of the default, for speed).
VEHICLES = 100


@pytest.fixture(scope='module')
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp('sumo_cache')


@pytest.fixture(scope='module')
def runs(cache):
    """One seeded run per family, made on first use."""
    made = {}

    def get(family, seed=1):
        if (family, seed) not in made:
            made[family, seed] = generate_network(
                draw_network(family, seed, vehicles=VEHICLES), cache
            )
        return made[family, seed]

    return get


def reachable(mapping, a, b):
    """Link b can be reached from the end of link a through one or more connections."""
    nxt = {}
    for c in mapping['connections']:
        nxt.setdefault(c['from'], []).append(c['to'])
    seen, todo = set(), deque(nxt.get(a, []))
    while todo:
        k = todo.popleft()
        if k == b:
            return True
        if k not in seen:
            seen.add(k)
            todo.extend(nxt.get(k, []))
    return False


def per_vehicle(ds):
    """Per target, the (stamp, station) of its first reports, in time order."""
    out = {}
    for k in np.flatnonzero(ds.kind == PASSAGE):
        out.setdefault(int(ds.target[k]), []).append((float(ds.stamp[k]), int(ds.station[k])))
    return {t: sorted(v) for t, v in out.items()}


@pytest.mark.parametrize('family', FAMILIES)
def test_the_draw_is_a_pure_function_of_family_and_seed_inside_the_ranges(family):
    a = draw_network(family, 7)
    assert json.dumps(a.to_json(), sort_keys=True) == json.dumps(
        draw_network(family, 7).to_json(), sort_keys=True
    )
    assert draw_network(family, 8).to_json() != a.to_json()
    ranges = NETWORK_FAMILIES[family]
    for seed in range(1, 21):
        d = draw_network(family, seed)
        for key, value in d.params.items():
            lo, hi = ranges[key]
            assert all(lo <= v <= hi for v in np.ravel(value)), (key, value)
        assert sum(r['probability'] for r in d.routes) == pytest.approx(1.0, abs=1e-4)
        ids = [e['id'] for e in d.edges]
        assert len(set(ids)) == len(ids)
        assert all(set(r['edges']) <= set(ids) for r in d.routes)
        for s in d.signals.values():
            assert 0 <= s['offset'] < s['cycle'] and ranges['split'][0] <= s['split']
        covered = {s['edge'] for s in d.stations}
        assert len(covered) >= ranges['coverage'][0] * len(ids) - 3
        assert all(0 < f < 1 for s in d.stations for f in s['fractions'])
    assert 'signal' in str(a) or family == 'interchange'


def test_overrides_fix_a_drawn_value_and_bad_ones_are_refused():
    base = draw_network('arterial', 3)
    fixed = draw_network('arterial', 3, vehicles=50, cycle=90.0, split=0.6)
    assert fixed.vehicles == 50 and {s['cycle'] for s in fixed.signals.values()} == {90.0}
    assert {s['split'] for s in fixed.signals.values()} == {0.6}
    assert fixed.routes == base.routes and fixed.edges == base.edges
    assert draw_network('arterial', 3, intersections=5).params['intersections'] == 5
    with pytest.raises(SumoError, match='cannot override lanes_a'):
        draw_network('arterial', 3, lanes_a=2)
    with pytest.raises(SumoError, match="unknown network family 'ring'"):
        draw_network('ring', 1)


@pytest.mark.parametrize('family', FAMILIES)
def test_the_layout_is_the_built_network_in_the_contract_form(family, runs):
    ds = runs(family)
    m = ds.mapping
    links = {link['id']: link for link in m['links']}
    assert sorted(links) == list(range(len(links)))
    assert [link['name'] for link in m['links']] == [e['id'] for e in ds.draw.edges]
    assert not any(link['name'].startswith(':') for link in m['links'])  # no internal lanes
    pairs = [(c['from'], c['to']) for c in m['connections']]
    assert len(set(pairs)) == len(pairs) and all(a != b for a, b in pairs)
    assert all(a in links and b in links for a, b in pairs)
    # the routes start on entries, end on exits and turn only where a connection is
    entries = {e['link'] for e in m['entries']}
    exits = {e['link'] for e in m['exits']}
    for route in ds.routes:
        assert route[0] in entries and route[-1] in exits
        assert all(p in pairs for p in zip(route, route[1:]))
    ids = [s['id'] for s in m['stations']]
    assert ids == list(range(len(ids)))
    assert len({s['name'] for s in m['stations']}) == len(ids)
    places = [(s['link'], s['position_m']) for s in m['stations']]
    assert len(set(places)) == len(places)
    for s in m['stations']:
        link = links[s['link']]
        assert 0 < s['position_m'] < link['length_m'] and s['lanes'] == link['lanes']
    # stations on most links, several on the long ones
    with_station = {s['link'] for s in m['stations']}
    assert len(with_station) >= 0.7 * len(links)
    per_link = np.bincount([s['link'] for s in m['stations']], minlength=len(links))
    spacing = ds.draw.params['spacing']
    for k in with_station:  # round(length / spacing) stations, the built link a bit shorter
        if links[k]['length_m'] > 2.5 * spacing + 40.0:
            assert per_link[k] >= 2
    if family == 'interchange' and 0 in with_station:  # a_in: >= 900 m, spacing <= 600 m
        assert per_link[0] >= 2
    # the yaml dump is the mapping
    assert yaml.safe_load(yaml.safe_dump(m)) == m


def test_the_junctions_are_those_of_the_family(runs):
    """Connections by hand: every movement but the U-turn at each junction."""

    def named(ds, key):
        name = {link['id']: link['name'] for link in ds.mapping['links']}
        if key == 'connections':
            return {(name[c['from']], name[c['to']]) for c in ds.mapping['connections']}
        return {name[e['link']] for e in ds.mapping[key]}

    ds = runs('interchange')
    assert named(ds, 'connections') == {
        ('a_in', 'a_out'), ('a_in', 'link_ac'), ('link_ac', 'd_acc'), ('c_in', 'd_acc'),
        ('d_acc', 'd_out'),
    }  # fmt: skip
    assert named(ds, 'entries') == {'a_in', 'c_in'} and named(ds, 'exits') == {'a_out', 'd_out'}
    lanes = {link['name']: link['lanes'] for link in ds.mapping['links']}
    assert lanes['d_acc'] == lanes['c_in'] + 1 == lanes['d_out'] + 1 and lanes['link_ac'] == 1
    ds = runs('arterial')
    n = ds.draw.params['intersections']
    cons = named(ds, 'connections')
    assert len(cons) == 4 * 3 * n  # four approaches, three moves each
    assert {('ae0', 'ae1'), ('ae0', 'n0_out'), ('ae0', 's0_out'), ('n0_in', 'ae1')} <= cons
    assert ('n0_in', 'aw0') in cons and ('ae1', 'aw1') not in cons  # no U-turn
    assert named(ds, 'entries') == {'ae0', f'aw{n}'} | {
        f'{s}{k}_in' for k in range(n) for s in 'ns'
    }
    ds = runs('grid')
    nx, ny = ds.draw.params['columns'], ds.draw.params['rows']
    assert len(named(ds, 'connections')) == 4 * 3 * nx * ny
    assert len(ds.mapping['links']) == 2 * (nx - 1) * ny + 2 * nx * (ny - 1) + 4 * (nx + ny)


@pytest.mark.parametrize('family', FAMILIES)
def test_every_vehicle_is_detected_on_its_route_in_an_order_the_connections_allow(family, runs):
    ds = runs(family)
    assert ds.stats['vehicles_arrived'] == ds.stats['vehicles_inserted'] == VEHICLES
    assert ds.stats['teleports'] == 0
    assert ds.n_targets >= 0.9 * VEHICLES and len(ds.routes) == ds.n_targets
    links, pos = ds.station_links, ds.station_positions
    lane_count = np.array([s['lanes'] for s in ds.mapping['stations']])
    assert np.all((ds.lane >= 0) & (ds.lane < lane_count[ds.station]))
    assert np.all(ds.speed > 0) and np.all((ds.length > 3.0) & (ds.length < 19.0))
    assert np.all(np.diff(ds.stamp) >= 0)
    for target, seq in per_vehicle(ds).items():
        route = ds.routes[target]
        assert all(links[s] in route for _, s in seq)  # every detection lies on its route
        for (t0, a), (t1, b) in zip(seq, seq[1:]):
            assert t1 > t0
            same_link_ahead = links[a] == links[b] and pos[b] > pos[a]
            assert same_link_ahead or reachable(ds.mapping, links[a], links[b]), (target, a, b)
            # and along the route: b's link does not come before a's
            assert route.index(links[b]) >= route.index(links[a])
    # without misses, a vehicle is reported by every station on its route, in route order
    on_link = {}
    for s in sorted(ds.mapping['stations'], key=lambda s: s['position_m']):
        on_link.setdefault(s['link'], []).append(s['id'])
    for target, seq in per_vehicle(ds).items():
        expected = [s for link in ds.routes[target] for s in on_link.get(link, [])]
        assert [s for _, s in seq] == expected, target


@pytest.mark.parametrize('family', FAMILIES)
def test_vehicles_turn_at_junctions(family, runs):
    ds = runs(family)
    after: dict[int, set[int]] = {}
    for route in ds.routes:
        for a, b in zip(route, route[1:]):
            after.setdefault(a, set()).add(b)
    turning = [a for a, nxt in after.items() if len(nxt) >= 2]
    assert turning, after
    # the detections see it too: from one station, vehicles reach stations on two links
    seen_next: dict[int, set[int]] = {}
    for seq in per_vehicle(ds).values():
        for (_, a), (_, b) in zip(seq, seq[1:]):
            if ds.station_links[a] != ds.station_links[b]:
                seen_next.setdefault(a, set()).add(int(ds.station_links[b]))
    assert max(len(v) for v in seen_next.values()) >= 2


def hop_times(ds):
    """Per consecutive pair of a vehicle's stations: (travel time, free-flow time) [s], the
    latter at the links' speed limits over the links and junctions between them, and whether
    the pair lies on two links (a junction between them)."""
    length = {link['id']: link['length_m'] for link in ds.mapping['links']}
    speed = {k: e['speed'] for k, e in enumerate(ds.draw.edges)}
    links, pos = ds.station_links, ds.station_positions
    out = []
    for target, seq in per_vehicle(ds).items():
        route = ds.routes[target]
        for (t0, a), (t1, b) in zip(seq, seq[1:]):
            i, j = route.index(links[a]), route.index(links[b])
            if i == j:
                free = (pos[b] - pos[a]) / speed[links[a]]
            else:
                way = route[i : j + 1]
                dist = [length[way[0]] - pos[a], *(length[k] for k in way[1:-1]), pos[b]]
                free = sum(x / speed[k] for x, k in zip(dist, way))
                free += sum(ds.junction_lengths[p] / speed[p[0]] for p in zip(way, way[1:]))
            out.append((t1 - t0, free, i != j))
    return np.array(out)


def test_signals_hold_vehicles_on_the_arterial(runs):
    hops = hop_times(runs('arterial'))
    time, free, junction = hops.T
    junction = junction.astype(bool)
    # between stations of one link, traffic flows near its free-flow time (desired speeds
    # spread around the limit); across a signalised junction a fair share waits at red
    # for well over the free-flow time
    assert np.median(time[~junction] / free[~junction]) < 1.3
    held = time[junction] > 2.0 * free[junction] + 5.0
    assert held.mean() > 0.1, held.mean()
    # on the interchange (no signals) almost nobody is held that long
    time, free, junction = hop_times(runs('interchange')).T
    assert np.mean(time > 2.0 * free + 5.0) < 0.02


def test_junction_lengths_cover_every_connection(runs):
    for family in FAMILIES:
        ds = runs(family)
        pairs = {(c['from'], c['to']) for c in ds.mapping['connections']}
        assert set(ds.junction_lengths) == pairs
        assert all(2.0 < x < 40.0 for x in ds.junction_lengths.values())


def test_the_same_seed_gives_the_same_dataset_and_another_seed_another(cache, runs):
    a = runs('interchange', 1)
    b = generate_network(draw_network('interchange', 1, vehicles=VEHICLES), cache)
    for name in ('station', 'stamp', 'speed', 'lane', 'length', 'target', 'kind'):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.routes == b.routes and a.mapping == b.mapping
    c = runs('interchange', 2)
    assert c.draw.to_json() != a.draw.to_json() and c.mapping != a.mapping


def test_the_dataset_is_written_as_the_contract_csv_and_layout(runs, tmp_path):
    ds = runs('grid')
    write_network_dataset(ds, tmp_path / 'd.csv', tmp_path / 'layout.yaml')
    text = (tmp_path / 'layout.yaml').read_text()
    assert text.startswith('# a road network from SUMO') and '- {id: 0, name: ' in text
    assert yaml.safe_load(text) == ds.mapping
    with open(tmp_path / 'd.csv', newline='') as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == [
        'sensor_id', 'position_m', 'stamp_s', 'velocity_mps', 'target_id', 'lane', 'length_m'
    ]  # fmt: skip
    assert len(rows) == len(ds)
    where = {s['id']: s['position_m'] for s in ds.mapping['stations']}
    for r in rows:
        assert float(r['position_m']) == pytest.approx(where[int(r['sensor_id'])], abs=1e-3)
    order = np.lexsort((ds.station, ds.stamp))
    assert [int(r['target_id']) for r in rows] == ds.target[order].tolist()
    assert [int(r['lane']) for r in rows] == ds.lane[order].tolist()


def test_the_measurement_model_applies_on_a_network(cache, runs):
    clean = runs('interchange')
    config = MeasurementConfig(miss_rate=0.2, false_alarm_rate=60.0, double_reports=False)
    ds = generate_network(draw_network('interchange', 1, vehicles=VEHICLES), cache, config)
    n_passages = int(np.sum(clean.kind == PASSAGE))
    assert ds.stats['passages'] == n_passages  # the same traffic, then measured
    assert ds.stats['missed'] == pytest.approx(0.2 * n_passages, rel=0.25)
    fa = ds.kind == FALSE_ALARM_KIND
    assert fa.sum() == ds.stats['false_alarms'] > 0 and np.all(ds.target[fa] == -1)
    lanes = np.array([s['lanes'] for s in ds.mapping['stations']])
    assert np.all(ds.lane[fa] < lanes[ds.station[fa]])
    assert not np.any((ds.target == -1) & ~fa)  # double reports removed


@pytest.mark.parametrize('family', ['arterial', 'grid'])
def test_the_signal_programs_are_retimed_to_the_draw(family, cache):
    import sumolib

    d = draw_network(family, 4)
    road = build_draw(d, cache)
    net = sumolib.net.readNet(str(road.net_file), withPrograms=True)
    program = {t.getID(): t for t in net.getTrafficLights()}
    assert set(program) == set(d.signals) and d.signals
    main = {e['id'] for e in d.edges if e['main']}
    root = ElementTree.parse(road.files.routes).getroot()
    for tl in root.iter('tlLogic'):
        s = d.signals[tl.get('id')]
        assert tl.get('programID') == 'draw' and float(tl.get('offset')) == s['offset']
        phases = [(float(p.get('duration')), p.get('state')) for p in tl.iter('phase')]
        assert sum(t for t, _ in phases) == pytest.approx(s['cycle'], abs=0.3)
        in_edge = {
            i: lane.getEdge().getID() for lane, _, i in program[tl.get('id')].getConnections()
        }
        green = {'main': 0.0, 'cross': 0.0}
        for t, state in phases:
            if 'y' not in state:
                major = {in_edge[i] for i, c in enumerate(state) if c == 'G'}
                green['main' if major & main else 'cross'] += t
        assert green['main'] / sum(green.values()) == pytest.approx(s['split'], abs=0.005)


def test_continuous_traffic_on_a_network_comes_in_time_order_along_its_connections(cache):
    draw = draw_network('interchange', 3, vehicles=VEHICLES)
    stream = network_stream(draw, duration=400.0, cache_dir=cache)
    mapping = stream.road.mapping  # known before SUMO starts
    passages = list(stream)
    assert np.all(np.diff([p.time for p in passages]) >= 0) and passages[-1].time < 400.0
    links = [s['link'] for s in mapping['stations']]
    pos = [s['position_m'] for s in mapping['stations']]
    seen: dict[str, list[int]] = {}
    for p in passages:
        assert p.position == pos[p.station] and p.vehicle  # no false alarms by default
        assert 0 <= p.lane < mapping['stations'][p.station]['lanes']
        if p.kind == PASSAGE:  # not a lane change's second report
            seen.setdefault(p.vehicle, []).append(p.station)
    # the demand runs on at the draw's flow: more vehicles than the episode of the draw
    assert len(seen) > 1.2 * VEHICLES and draw.flow * 400.0 / 3600.0 > len(seen) * 0.8
    for vehicle, stations in seen.items():
        for a, b in zip(stations, stations[1:]):
            ahead = links[a] == links[b] and pos[b] > pos[a]
            assert ahead or reachable(mapping, links[a], links[b]), (vehicle, a, b)
