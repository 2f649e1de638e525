"""``mlkm plot`` on the shipped sample bag (bags/sample: 3 episodes of 50 vehicles x 20
stations, recorded with an older TrackArray definition), and the diagram a demo writes
beside its bag."""

import shutil
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from mlkm_assoc import cli
from mlkm_assoc.timespace_bag import read_bag
from mlkm_assoc.timespace_plot import plot_beside_bag
from mlkm_core.metrics import score
from mlkm_core.timespace import time_space
from mlkm_core.types import Detections

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / 'bags' / 'sample'
sys.path.insert(0, str(REPO / 'scripts'))


def test_plot_of_the_sample_bag_writes_a_png(tmp_path, capsys):
    png = tmp_path / 'sample.png'
    assert cli.main(['plot', '--input', str(SAMPLE), '--output', str(png)]) == 0
    out = capsys.readouterr().out
    assert out.startswith('3000 detections, 150 tracks, 0 unassigned, 2850 links, ')
    with Image.open(png) as image:
        assert image.format == 'PNG' and image.size[0] > 500


def test_the_bag_joins_tracks_and_truth_as_the_recording_scorer_did():
    from replay import inspect_bag

    data = read_bag(SAMPLE)
    assert data.notes == [] and data.stations.size == 20
    assert len(data.stamp) == 3000 and np.unique(data.labels).size == 150
    ts = time_space(data.position, data.stamp, data.labels, data.target)
    # the scorer node's link precision, recorded in the bag, from the same join
    _, _, recorded, _ = inspect_bag(SAMPLE)
    assert sorted(recorded) == [0, 1, 2]
    shared = sum(round(s.link_precision * 950) for s in recorded.values())  # 950 links each
    sensor = np.searchsorted(data.stations, data.position)
    dets = Detections(sensor, data.stamp, np.ones(3000), data.target)
    mine = score(dets, data.labels)
    assert round(mine.link_precision * len(ts.links)) == shared
    # a red link is a link the scorer did not share; the others join one vehicle twice
    # with one of its detections elsewhere in between
    assert 0 < ts.n_wrong <= len(ts.links) - shared


def test_a_demo_writes_the_diagram_beside_its_bag(tmp_path):
    bag = tmp_path / 'demo_x'
    shutil.copytree(SAMPLE, bag)
    line = plot_beside_bag(bag)
    png = tmp_path / 'demo_x_timespace.png'
    assert line.startswith(f'time-space diagram: {png}  (3000 detections')
    with Image.open(png) as image:
        image.verify()
    assert 'not written' in plot_beside_bag(tmp_path / 'no_bag')
