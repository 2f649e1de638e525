"""The README section of the stream part (``mlkm bench --only stream``)."""

from __future__ import annotations


def _ms(x: float | None) -> str:
    return '—' if x is None else f'{1000 * x:.1f}'


def _mib(x: float | None) -> str:
    return '—' if x is None else f'{x / 2**20:.1f}'


def report_lines(stream: dict) -> list[str]:
    L = ['## Stream mode (open road)', '']
    if not stream.get('lag') and not stream.get('latency'):
        return L + [str(stream.get('status', 'not run')), '']
    la = stream.get('load_average_1min_start')
    L += [
        '`mlkm bench --only stream`: `association_node` with `mode:=stream` (its default '
        'method and lag) as a separate process over loopback DDS; shared 2-core machine, 1-min '
        f'load average {la:.1f} at the start and '
        f'{stream.get("load_average_1min_end", 0):.1f} at the end of the part.',
        '',
        '### Latency',
        '',
        "The node's own figure from /diagnostics (`stream.latency_p50/p95/p99`): for every "
        "detection, from its arrival in the node's callback to the publication of the "
        'TrackArray answering the batch that held it (reorder buffer, tracker process and '
        'publish included), over the last 10,000 detections. Source: `sensor_sim` continuous '
        '(paper model, 20 sensors, Poisson arrivals), paced by real_time_factor.',
        '',
        '| nominal rate | arrival rate [veh/s] | real_time_factor | delivered [det/s] | '
        'detections | p50 [ms] | p95 [ms] | p99 [ms] | max [ms] | p95 <= 50 ms |',
        '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |',
    ]
    for name, r in (stream.get('latency') or {}).items():
        if 'latency_p95' not in r:
            L.append(f'| {name} | {r.get("status", "")} |')
            continue
        rate = r['delivered_rate']
        L.append(
            f'| {name} | {r["arrival_rate"]:g} | {r["real_time_factor"]:g} | '
            f'{"—" if rate is None else f"{rate:.0f}"} | {r["received"]} | '
            f'{_ms(r["latency_p50"])} | {_ms(r["latency_p95"])} | {_ms(r["latency_p99"])} | '
            f'{_ms(r["latency_max"])} | {"yes" if r["ok"] else "**no**"} |'
        )
    parts = [
        (name, r) for name, r in (stream.get('latency') or {}).items() if r.get('latency_parts')
    ]
    if parts:
        L += [
            '',
            "The latency's parts (`stream.latency_<part>_p50/p95`): queued from the node to "
            'the tracker process, held by the reorder buffer, in the tracker until its answer '
            'was sent, from then to the publication; and how far the window solves were '
            'behind when the source stopped (`stream.commit_lag` [s of stamp time]).',
            '',
            '| nominal rate | queue p50/p95 [ms] | hold p50/p95 [ms] | tracker p50/p95 [ms] '
            '| publish p50/p95 [ms] | commit lag at the end [s] |',
            '| --- | --- | --- | --- | --- | --- |',
        ]
        for name, r in parts:
            cells = [
                f'{_ms(q.get("p50"))} / {_ms(q.get("p95"))}'
                for q in (r['latency_parts'][p] for p in ('queue', 'hold', 'tracker', 'publish'))
            ]
            lag = r.get('commit_lag_at_end')
            L.append(
                f'| {name} | ' + ' | '.join(cells) + f' | {"—" if lag is None else f"{lag:.0f}"} |'
            )
    L += ['', '### Throughput', '']
    tp = stream.get('throughput') or {}
    if tp.get('ratio') is not None:
        L += [
            f'{tp["source"]} into a bare rclpy subscriber (counts only) and into the node, '
            f'{len(tp["bare"])} interleaved runs each, medians. Rate = detections / (last '
            "arrival - first arrival); the node's from its /diagnostics (`received` by message "
            'stamp from the first sample on, last arrival from `stream.idle`).',
            '',
            '| bare [det/s] | association node [det/s] | ratio (target >= 0.70) |',
            '| --- | --- | --- |',
            f'| {tp["bare_rate"]:.0f} | {tp["association_rate"]:.0f} | {tp["ratio"]:.3f} |',
            '',
            'Per run [det/s]: bare '
            + ', '.join(f'{b["ingest_rate"]:.0f}' for b in tp['bare'])
            + '; association '
            + ', '.join(f'{a["ingest_rate"] or 0:.0f}' for a in tp['association'])
            + '.',
        ]
    else:
        L.append(str(tp.get('status', 'not run')))
    L += ['', '### Memory', '']
    mem = stream.get('memory') or {}
    if mem.get('counts'):
        c, p = mem['counts'], mem['probe']
        L += [
            f'{mem["scenario"]}, {mem["duration"] / 60:.0f} simulated minutes in '
            f'{mem["wall_s"] / 60:.1f} min wall (a {p["duration"] / 60:.0f}-minute probe took '
            f'{p["wall_s"]:.0f} s: an hour extrapolates to {p["hour_estimate_s"] / 60:.1f} '
            'min). VmRSS of the node and of its tracker process sampled every second; progress '
            "= the tracker's committed stamp time; early: median over the second sixth, late: "
            'median over the last sixth; passes at a growth <= 10 %. Largest working set: '
            f'{mem.get("working_set_max", "—")} detections.',
            '',
            '| process | RSS early [MiB] | RSS late [MiB] | growth |',
            '| --- | --- | --- | --- |',
        ]
        for label, key in (('node', 'rss_node'), ('tracker', 'rss_tracker'), ('sum', 'rss_total')):
            r = mem.get(key) or {}
            g = r.get('growth')
            L.append(
                f'| {label} | {_mib(r.get("early_bytes"))} | {_mib(r.get("late_bytes"))} | '
                f'{"—" if g is None else f"{100 * g:+.1f} %"} |'
            )
        L += [
            '',
            f'Nothing lost: {mem["nothing_lost"]} (source published {c["source_published"]}, '
            f'node received {c["received"]}, accepted {c["accepted"]}, rejected '
            f'{c["rejected"]}, {c["pushed"]} through the tracker, working set '
            f'{c["working_set"]} after the quiet-road flush, {c["tracks_final"]} tracks final).',
            '',
            '![stream rss](stream_rss.png)',
        ]
        if mem.get('note'):
            L += ['', mem['note']]
    else:
        L.append(str(mem.get('status', 'not run')))
    L += ['', '### Accuracy against the commit lag', '']
    lag = stream.get('lag') or {}
    fams = lag.get('families') or {}
    if fams:
        lags = [str(x) for x in lag['lags']]
        L += [
            f'Offline, the core only: `{lag["method"]}` stream (pushed in stamp order, flushed '
            'at the end) against its batch association of the same datasets; '
            + '; '.join(lag['scenarios'][f] for f in fams)
            + f'. Default lag {lag["default_lag"]:g} s; target: within 0.5 points of batch.',
            '',
            '| datasets | batch [%] | '
            + ' | '.join(f'lag {float(x):g} s' for x in lags)
            + ' | stream - batch at the default lag [points] |',
            '|' + ' --- |' * (len(lags) + 3),
        ]
        for f, r in fams.items():
            L.append(
                f'| {f} (n={r["datasets"]}) | {100 * r["batch"]:.2f} | '
                + ' | '.join(f'{100 * r["stream"][x]:.2f}' for x in lags)
                + f' | {-r["loss_points"]:+.2f}{"" if r["ok"] else " **no**"} |'
            )
        L += ['', '![stream lag](stream_lag.png)']
    L.append('')
    return L
