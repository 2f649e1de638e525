"""The soak's judgement of a resident-set curve, and its report."""

from __future__ import annotations

import numpy as np

from mlkm_experiments.bench import soak

MIB = 2**20


def test_flat_curve_after_warm_up_passes():
    p = np.linspace(0.0, 1.0, 201)
    rss = np.where(p < 0.05, 80 * MIB, 160 * MIB)  # start-up growth before 10 % is not judged
    rss = rss + (np.arange(p.size) % 3) * 0.5 * MIB  # jitter
    r = soak.rss_growth(p, rss)
    assert r['ok'] is True
    assert abs(r['growth']) < 0.01
    assert r['early_bytes'] == np.median(rss[(p >= 0.1) & (p < 0.2)])


def test_steadily_growing_curve_fails():
    p = np.linspace(0.0, 1.0, 201)
    rss = 160 * MIB * (1.0 + 0.3 * p)  # +30 % over the run: a leak
    r = soak.rss_growth(p, rss)
    assert r['ok'] is False
    # early median at p = 0.15, late median at p = 0.95: 1.285 / 1.045 - 1
    assert abs(r['growth'] - (1.285 / 1.045 - 1)) < 1e-3


def test_growth_just_inside_and_just_outside_the_limit():
    p = np.linspace(0.0, 1.0, 101)
    for end, ok in ((1.09, True), (1.12, False)):
        rss = np.where(p >= 0.9, end * 100 * MIB, 100 * MIB)
        assert soak.rss_growth(p, rss)['ok'] is ok


def test_no_sample_in_a_window_is_not_judged():
    r = soak.rss_growth([0.0, 0.05, 1.0], [1, 1, 1])
    assert r['ok'] is None and r['growth'] is None


def test_report_of_a_finished_soak(tmp_path):
    samples = [
        {'t': 0.25 * k, 'episodes': k, 'association_node': 100 * MIB, 'scorer_node': 90 * MIB}
        for k in range(21)
    ]
    out = {
        'scenario': {'episodes': 20, 'targets': 10, 'sensors': 5, 'detections': 1000},
        'samples': samples,
        'status': 'ok',
    }
    out['scenario'].update(method='mlkm', real_time_factor=250.0)
    out.update(seconds=5.0, sample_period_s=0.25, growth_limit=0.1)

    class Score:
        total, truth_complete, accuracy = 50, True, 1.0

    soak._evaluate(
        out,
        {e: Score() for e in range(20)},
        {'association_node': {'received': '1000', 'rejected': '0'}},
        1000,
    )
    assert out['nothing_lost'] and out['rss_ok'] and out['passed']
    text = '\n'.join(soak.report_lines(out))
    assert '| association_node | 100.0 | 100.0 | +0.0 % | yes |' in text
    assert soak.plot(tmp_path, out) == 'soak.png' and (tmp_path / 'soak.png').stat().st_size
    # one detection short: lost
    soak._evaluate(
        out,
        {e: Score() for e in range(20)},
        {'association_node': {'received': '999', 'rejected': '0'}},
        1000,
    )
    assert not out['nothing_lost'] and not out['passed']


def test_report_only_rewrites_the_readme_from_the_json_files(tmp_path, monkeypatch):
    import json

    from mlkm_experiments import bench

    def must_not_run(*args, **kwargs):
        raise AssertionError('--report-only ran a part')

    monkeypatch.setattr(soak, 'run_soak', must_not_run)
    samples = [
        {'t': k, 'episodes': k, 'association_node': 100 * MIB, 'scorer_node': (90 + k) * MIB}
        for k in range(21)
    ]
    data = {
        'scenario': {'episodes': 20, 'targets': 10, 'sensors': 5, 'detections': 1000},
        'samples': samples,
        'status': 'ok',
        'seconds': 21.0,
        'sample_period_s': 0.25,
        'growth_limit': 0.1,
        'wall_s': 30.0,
        'date': '2026-01-01 00:00 UTC',
    }
    data['scenario'].update(method='mlkm', real_time_factor=250.0)

    class Score:
        total, truth_complete, accuracy = 50, True, 1.0

    soak._evaluate(data, {e: Score() for e in range(20)}, {}, 1000)
    (tmp_path / 'soak.json').write_text(json.dumps(data))
    assert bench.main(['--report-only', '--output', str(tmp_path)]) == 0
    readme = (tmp_path / 'README.md').read_text()
    assert 'soak 0.5 min (2026-01-01 00:00 UTC)' in readme
    # scorer: median of 92, 93 MiB (episodes 2-3 of 20) vs of 108..110 MiB (18-20): +17.8 %
    assert '| scorer_node | 92.5 | 109.0 | +17.8 % | **no** |' in readme
    summary = json.loads((tmp_path / 'summary.json').read_text())
    soak_targets = {t['target']: t['met'] for t in summary['targets'] if 'soak' in t['target']}
    assert list(soak_targets.values()) == [False, False]  # RSS grew; received count unknown
    assert (tmp_path / 'soak.png').exists()
