"""Is it the fit or the model? The network ``assignment`` with its model fitted on the truth.

``python -m mlkm_experiments.network_oracle [--seeds N]`` (from the repository root) runs, on
the SUMO network families of ``mlkm bench --only network`` (seeds 1..N, time and speed only),
the network ``assignment`` twice: as it is (its model fitted on the links of its own passes)
and with its model (motion, turn shares, time lost per connection and per hop) fitted on the
*true* links, an oracle no method has. Where the oracle links no better, the errors are not
those of a badly fitted model but of the model itself.
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np

from mlkm_core.metrics import accuracy
from mlkm_core.model.motion import MotionParams
from mlkm_core.network_assoc import MAX_SKIP, associate_network, network_hops
from mlkm_core.network_assoc.fit import fit_model
from mlkm_core.network_assoc.hops import Hops
from mlkm_core.network_assoc.linking import Links, solve
from mlkm_core.types import Detections

from .bench.network import FAMILIES, _dataset, variant_of


def true_links(hops: Hops, d: Detections) -> Links:
    """The consecutive detections of each vehicle, with the hop (fewest stations skipped)
    between their stations; pairs no hop joins are left out."""
    order = np.lexsort((d.stamp, d.target))
    a, b = order[:-1], order[1:]
    same = (d.target[a] == d.target[b]) & (d.target[a] >= 0)
    a, b = a[same], b[same]
    ends = zip(hops.src.tolist(), hops.dst.tolist(), hops.skipped.tolist(), strict=True)
    key = {(s, t, k): h for h, (s, t, k) in enumerate(ends)}
    keep, made = [], []
    for i, (x, y) in enumerate(zip(a.tolist(), b.tolist(), strict=True)):
        pair = (int(d.sensor_index[x]), int(d.sensor_index[y]))
        h = next((key[(*pair, k)] for k in range(MAX_SKIP + 1) if (*pair, k) in key), None)
        if h is not None:
            keep.append(i)
            made.append(h)
    keep_a = np.array(keep, np.int64)
    return Links(a[keep_a], b[keep_a], np.array(made, np.int64))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m mlkm_experiments.network_oracle')
    parser.add_argument('--seeds', type=int, default=3, help='datasets per family (1..N)')
    parser.add_argument('--cache-dir', default=None, help='keep the SUMO datasets here')
    args = parser.parse_args(argv)
    warnings.simplefilter('ignore')
    print('family seed assignment_% fitted_on_truth_%')
    for family in FAMILIES:
        for seed in range(1, args.seeds + 1):
            _, net, d = _dataset(family, seed, {}, args.cache_dir)
            d = variant_of(d, 'time_speed')
            hops = network_hops(net, MAX_SKIP)
            model = fit_model(net, hops, d, true_links(hops, d), MotionParams())
            oracle, _ = solve(hops, d, model.motion, model.junctions)
            own = associate_network(net, d)
            print(
                f'{family} {seed} {100 * accuracy(own, d.target).accuracy:.2f} '
                f'{100 * accuracy(oracle, d.target).accuracy:.2f}',
                flush=True,
            )
    return 0


if __name__ == '__main__':
    sys.exit(main())
