"""``mlkm associate --layout network.yaml``: a detections CSV on a road network.

The layout file in its network form (``mlkm_core.network_file``: links, connections,
stations on links) places the rows' stations by their ``sensor_id``; the association is a
network method (``mlkm_core.network_assoc.NETWORK_METHODS``). What the single road's options
mean there: ``--method`` one of the network methods, ``--seed`` as on one road; ``--stream
[--lag S]`` pushes the rows in stamp order through the network's stream
(``mlkm_core.network_assoc.stream``, which links with ``assignment``); ``--entries`` /
``--exits`` (the file gives the network's entries and exits), ``--targets`` and
``--segment-size`` do not apply and are refused when given.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mlkm_core.network import RoadNetwork

#: the method the network stream links with
STREAM_METHOD = 'assignment'


def load_network(args: argparse.Namespace) -> tuple[RoadNetwork | None, str | None]:
    """(the network of ``--layout``, None) or (None, why it cannot be used)."""
    from mlkm_core.associators import AssociatorConfig
    from mlkm_core.layout_file import LayoutFileError
    from mlkm_core.network_assoc import NETWORK_METHODS
    from mlkm_core.network_file import read_network_file

    try:
        net = read_network_file(Path(args.layout))
    except LayoutFileError as exc:
        return None, str(exc)
    if args.method not in NETWORK_METHODS:
        known = ', '.join(sorted(NETWORK_METHODS))
        return None, f'--method {args.method} does not associate road networks; use {known}'
    given = [
        flag
        for flag, on in (
            ('--entries', bool(args.entries)),
            ('--exits', bool(args.exits)),
            ('--targets', args.targets is not None),
            ('--segment-size', args.segment_size != AssociatorConfig.segment_size),
        )
        if on
    ]
    if given:
        return None, (
            f'{", ".join(given)}: not with --layout (on a road network the layout file gives '
            'the entries and exits, and the network methods need no number of targets)'
        )
    if args.stream and args.method != STREAM_METHOD:
        return None, f'--stream on a road network links with --method {STREAM_METHOD}'
    return net, None


def stream_config(args: argparse.Namespace):
    """The network stream's settings: ``--lag``."""
    from mlkm_core.network_assoc.stream import NetworkStreamConfig

    return NetworkStreamConfig(lag=args.lag)


def needs_network(method: str) -> str | None:
    """Why ``method`` cannot run without ``--layout`` (a network-only method), or None."""
    from mlkm_core.associators import available_methods

    if method in available_methods():
        return None
    return f'--method {method} associates road networks: give their layout file with --layout'


def associate(net: RoadNetwork, dets, method: str, seed: int):
    """The labels of ``dets`` (station indexes of ``net``) by the network ``method``."""
    from mlkm_core.network_assoc import associate_network

    return associate_network(net, dets, method, seed)
