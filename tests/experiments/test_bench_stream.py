"""The stream bench part's verdicts on hand-made numbers (no ROS graph, no SUMO)."""

import pytest

from mlkm_experiments.bench.stream import latency_ok
from mlkm_experiments.bench.stream_graph import ingest_rate
from mlkm_experiments.bench.stream_lag import lag_verdict
from mlkm_experiments.bench.stream_memory import memory_verdict, tracker_progress
from mlkm_experiments.bench.stream_report import report_lines
from mlkm_experiments.bench.targets import stream_targets

MIB = 2**20


def rss_run(node_mib, tracker_mib):
    """One RSS sample a minute of stamp time the tracker committed (0 to 11 min), 590
    detections through it (the node received all 600 at once, the tracker took them all at
    the start)."""
    return [
        {
            't': float(i),
            'received': 600,
            'pushed': 590,
            'committed': 1000.0 + 60.0 * i,
            'working_set': 590 - 50 * i,
            'node': n * MIB,
            'tracker': k * MIB,
        }
        for i, (n, k) in enumerate(zip(node_mib, tracker_mib, strict=True))
    ]


COUNTS = {
    'received': '600',
    'accepted': '590',
    'rejected': '10',
    'stream.pushed': '590',
    'stream.working_set': '0',
    'stream.tracks_final': '40',
}


def test_ingest_rate_runs_from_the_first_sample_to_the_last_arrival():
    samples = [
        {'t': 10.0, 'received': 0, 'idle': None},
        {'t': 10.5, 'received': 100, 'idle': 0.0},
        {'t': 11.0, 'received': 400, 'idle': 0.0},
        # the last arrival was 0.25 s before this sample: 600 - 100 in 1.0 s
        {'t': 11.75, 'received': 600, 'idle': 0.25},
        {'t': 12.25, 'received': 600, 'idle': 0.75},
    ]
    assert ingest_rate(samples) == pytest.approx(500.0)
    assert ingest_rate(samples[:2]) is None  # one sample with detections: no interval


def test_latency_target_is_on_the_p95():
    assert latency_ok(0.05) is True
    assert latency_ok(0.0501) is False
    assert latency_ok(None) is None


def test_memory_passes_on_a_flat_curve_after_the_warm_up():
    # 12 minutes: warm-up growth in the first sixth, flat from then on (+5 % at the end)
    node = [50, 80, 100, 100, 100, 100, 100, 100, 100, 100, 105, 105]
    v = memory_verdict(rss_run(node, [20] * 12), COUNTS, 600)
    # second sixth: minutes 2-3 (100 + 20), last sixth: minutes 10-11 (105 + 20)
    assert v['rss_total']['early_bytes'] == 120 * MIB
    assert v['rss_total']['late_bytes'] == 125 * MIB
    assert v['rss_total']['growth'] == pytest.approx(5 / 120)
    assert v['nothing_lost'] is True
    assert v['ok'] is True


def test_progress_is_the_trackers_committed_time_not_what_it_was_given():
    # the node takes a backlog at once and the tracker commits it later: a sample before the
    # first commit is at progress 0, the others run from the first commit to the last
    samples = [{'committed': None}, {'committed': 100.0}, {'committed': 400.0}, {}]
    samples.append({'committed': 1000.0})
    assert tracker_progress(samples) == [0.0, 0.0, pytest.approx(1 / 3), 0.0, 1.0]
    assert tracker_progress([{'committed': None}, {'committed': 5.0}]) is None
    # a backlog working through: RSS held by the backlog (high, then flat) passes, the
    # working set's peak is reported
    node = [100] * 12
    v = memory_verdict(rss_run(node, [300] + [400] * 11), COUNTS, 600)
    assert v['rss_tracker']['growth'] == 0.0 and v['rss_ok'] is True
    assert v['working_set_max'] == 590


def test_memory_fails_on_growth_and_on_a_lost_detection():
    node = [100 + 5 * i for i in range(12)]  # grows for ever: 110..115 -> 150..155
    v = memory_verdict(rss_run(node, [0] * 12), COUNTS, 600)
    assert v['rss_ok'] is False and v['ok'] is False
    flat = memory_verdict(rss_run([100] * 12, [0] * 12), COUNTS, 601)  # one never arrived
    assert flat['rss_ok'] is True and flat['nothing_lost'] is False
    left = memory_verdict(
        rss_run([100] * 12, [0] * 12), {**COUNTS, 'stream.working_set': '3'}, 600
    )
    assert left['nothing_lost'] is False


def test_lag_verdict_is_half_a_point():
    assert lag_verdict(0.9950, 0.9901) == {'loss_points': pytest.approx(0.49), 'ok': True}
    assert lag_verdict(0.9950, 0.9899)['ok'] is False
    assert lag_verdict(0.98, 0.99)['ok'] is True  # the stream may beat batch


def test_targets_and_report_from_a_stream_result():
    stream = {
        'load_average_1min_start': 3.0,
        'load_average_1min_end': 4.0,
        'latency': {
            '100/s': {
                'arrival_rate': 0.5,
                'real_time_factor': 10.0,
                'delivered_rate': 98.0,
                'received': 3000,
                'latency_p50': 0.002,
                'latency_p95': 0.030,
                'latency_p99': 0.2,
                'latency_max': 0.5,
                'ok': True,
            },
            '1000/s': {'status': 'failed: timed out'},
        },
        'lag': {
            'method': 'multiframe',
            'default_lag': 15.0,
            'lags': [5.0, 15.0],
            'scenarios': {'clutter': 'paper clutter'},
            'families': {
                'clutter': {
                    'datasets': 2,
                    'batch': 0.99,
                    'stream': {'5.0': 0.97, '15.0': 0.988},
                    **lag_verdict(0.99, 0.988),
                }
            },
        },
    }
    got = {t['target']: t for t in stream_targets(stream)}
    assert got['stream: p95 latency <= 50 ms at 100/s']['met'] is True
    assert '30.0 ms' in got['stream: p95 latency <= 50 ms at 100/s']['value']
    assert got['stream: p95 latency <= 50 ms at 1000/s']['met'] is None
    lag = got['stream: clutter accuracy at lag 15 s within 0.5 points of batch']
    assert lag['met'] is True and '98.80 % vs 99.00 %' in lag['value']
    assert got['stream: >= 70% of bare subscriber ingest']['met'] is None
    text = '\n'.join(report_lines(stream))
    assert '| 100/s | 0.5 | 10 | 98 | 3000 | 2.0 | 30.0 | 200.0 | 500.0 | yes |' in text
    assert '| clutter (n=2) | 99.00 | 97.00 | 98.80 | -0.20 |' in text
