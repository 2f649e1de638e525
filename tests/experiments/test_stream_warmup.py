"""``python -m mlkm_experiments.stream_warmup``: on the third placement of five closed-road
NGSIM loops (time and speed), the stream whose windows are given the gap delays batch fits on
the whole recording gets clearly more right than the stream that fits them as it goes, and the
plain stream of the experiment is the benchmark's."""

from __future__ import annotations

from mlkm_core.metrics import accuracy
from mlkm_core.streaming import StreamConfig
from mlkm_core.trajectories import read_trajectories
from mlkm_experiments.bench import real
from mlkm_experiments.bench.common import time_speed_only
from mlkm_experiments.bench.stream_lag import stream_labels
from mlkm_experiments.stream_warmup import GivenDelays, stream_accuracy, whole_recording_delay


def test_the_whole_recordings_gap_delays_lift_the_streams_warm_up(repo_root):
    traj = read_trajectories(repo_root / real.DATA)
    (ds,) = real.datasets(traj, 5, 'closed', [3])
    ds = time_speed_only(ds)
    own = stream_accuracy(ds)
    bench = stream_labels(ds, StreamConfig.lag)
    assert own == accuracy(bench, ds.detections.target).accuracy
    delay = whole_recording_delay(ds)
    assert delay is not None and delay.gap_var.max() > 0.0
    given = stream_accuracy(ds, GivenDelays(delay))
    assert given > own + 0.03  # 87.6 against 82.5 % (batch multiframe: 88.7 %)
