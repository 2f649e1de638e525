"""``track_merge``: one view of the tracks of a road's shards, on /mlkm/tracks.

Subscribes to every shard's ``<namespace>/mlkm/tracks`` and to /mlkm/handoff, joins the
pieces of a vehicle's track that the shards continued from one another
(:class:`mlkm_core.shards.merge.TrackMerge`: the id of the shard where the track began, every
detection, one status), and publishes stream TrackArrays that a scorer, a recorder or a
user's tracker reads as they would read one association node's. Its run (TrackArray.run) is
its own start; the track ids are the shards' (unique across shards: ``id % 1024`` is the
shard the track began in).
"""

from __future__ import annotations

import math
import sys
import time
from collections import Counter

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node

from mlkm_core.shards.desk import DEFAULT_HORIZON
from mlkm_core.shards.merge import MergeOut, TrackMerge
from mlkm_core.shards.regions import MAX_SHARDS
from mlkm_ros import conversions as conv
from mlkm_ros import lifecycle, qos
from mlkm_ros.handoff_conversions import handoff_from_msg, stream_rows_from_msg
from mlkm_ros.params import ParamSpec, declare_parameters, positive
from mlkm_ros.publishing import PublishTimeout, tracks_publisher
from mlkm_ros.track_conversions import stream_tracks_to_msg
from road_sensor_msgs.msg import TrackArray, TrackHandoff

SPECS = [
    ParamSpec('shard_count', 2, 'shards whose tracks are merged [-]', 1, MAX_SHARDS,
              read_only=True),
    ParamSpec(
        'shard_namespace_prefix',
        '/shard_',
        'shard k publishes its tracks under <prefix><k>/mlkm/tracks [-]',
        read_only=True,
    ),
    ParamSpec(
        'handoff_horizon',
        DEFAULT_HORIZON,
        "the shards' handoff_horizon: an offered track nobody took is final once the next "
        'shard settled this long past it [s]',
        1e-3,
        1e6,
        check=positive,
        read_only=True,
    ),
    ParamSpec(
        'wait_for_track_subscribers',
        0,
        'hold the merged tracks until /mlkm/tracks has this many subscribers [-]',
        0,
        1000,
        read_only=True,
    ),
    ParamSpec('diagnostics_period', 1.0, 'period of /diagnostics [s]', 1e-3, 3600.0,
              check=positive, read_only=True),
]  # fmt: skip


class TrackMergeNode(Node):
    """The shards' TrackArrays and hand-offs in, one TrackArray stream out."""

    def __init__(self, node_name: str = 'track_merge', **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        p = declare_parameters(self, SPECS)
        self._count = p['shard_count']
        self._merge = TrackMerge(self._count, p['handoff_horizon'])
        self._run = time.time_ns() // 1000
        self._method = ''
        self._counts: Counter = Counter()
        self._last_until = -math.inf  # committed_until last published [s]
        # a slow subscriber holds the merge back (and through it the shards), nothing is lost
        self._pub = tracks_publisher(self, p['wait_for_track_subscribers'])
        self._diag_pub = self.create_publisher(
            DiagnosticArray, qos.DIAGNOSTICS_TOPIC, qos.DIAGNOSTICS_QOS
        )
        prefix = p['shard_namespace_prefix']
        self._subs = [
            self.create_subscription(
                TrackArray,
                f'{prefix}{k}/{qos.TRACKS_TOPIC}',
                lambda msg, k=k: self._on_tracks(k, msg),
                qos.TRACKS_QOS,
            )
            for k in range(self._count)
        ]
        self._handoff_sub = self.create_subscription(
            TrackHandoff, qos.HANDOFF_TOPIC, self._on_handoff, qos.HANDOFF_READER_QOS
        )
        self._timer = self.create_timer(p['diagnostics_period'], self._publish_diagnostics)
        self.get_logger().info(
            f'merging the tracks of {self._count} shards under {prefix}<k>/{qos.TRACKS_TOPIC}'
        )

    def _on_tracks(self, shard: int, msg: TrackArray) -> None:
        if msg.mode != TrackArray.MODE_STREAM:
            self._refuse('episodes_tracks', f'shard {shard} published episodes tracks')
            return
        try:
            tracks, unassigned = stream_rows_from_msg(msg)
        except ValueError as exc:
            self._refuse('malformed_tracks', f'shard {shard}: {exc}')
            return
        self._method = msg.method or self._method
        self._counts['track_arrays'] += 1
        until = conv.time_to_ns(msg.committed_until) / conv.NS_PER_S
        self._emit(self._merge.add_tracks(shard, msg.run, tracks, unassigned, until))

    def _on_handoff(self, msg: TrackHandoff) -> None:
        if msg.shard >= self._count:
            self._refuse('unknown_shard', f'hand-off of shard {msg.shard}')
            return
        try:
            h = handoff_from_msg(msg)
        except ValueError as exc:
            self._refuse('malformed_handoff', f'shard {msg.shard}: {exc}')
            return
        self._counts['handoffs'] += 1

        self._emit(
            self._merge.add_handoff(
                h.shard,
                h.run,
                h.offered_stamps(),
                h.continuations,
                h.settled_until,
                h.newest,
            )
        )

    def _emit(self, out: MergeOut) -> None:
        if not out and out.committed_until <= self._last_until:
            return
        until = out.committed_until
        msg = stream_tracks_to_msg(
            method=self._method,
            tracks=out.tracks,
            unassigned=out.unassigned,
            committed_until_ns=round(until * conv.NS_PER_S) if math.isfinite(until) else 0,
            solve_time=0.0,
            stamp_ns=self.get_clock().now().nanoseconds,
            run=self._run,
        )
        try:
            self._pub.publish(msg)
        except PublishTimeout as exc:  # a subscriber alive but stuck for the whole deadline
            self._counts['publish_timeouts'] += 1  # the tracks of that TrackArray are lost
            self.get_logger().error(f'merged tracks not published: {exc}')
            return
        self._last_until = until
        self._counts['published'] += 1
        self._counts['tracks_published'] += len(out.tracks)

    def _refuse(self, reason: str, text: str) -> None:
        self._counts[f'rejected_{reason}'] += 1
        self.get_logger().error(text, throttle_duration_sec=2.0)

    def _publish_diagnostics(self) -> None:
        values = dict(sorted(self._counts.items()))
        values['continued'] = self._merge.continued
        values['retired'] = self._merge.retired
        until = self._merge.committed_until
        values['committed_until'] = f'{until:.3f}' if math.isfinite(until) else 'none'
        values['tracks_held'] = self._pub.held
        rejected = any(k.startswith('rejected_') for k in values)
        if rejected:
            message = 'inputs rejected'
        elif 'publish_timeouts' in values:
            message = 'merged tracks lost: a subscriber acknowledged nothing for the deadline'
        else:
            message = 'merging'
        warn = message != 'merging'
        self._diag_pub.publish(
            conv.diagnostics_to_msg(
                name=self.get_fully_qualified_name(),
                hardware_id='mlkm_assoc',
                level=(DiagnosticStatus.WARN if warn else DiagnosticStatus.OK)[0],
                message=message,
                values=values,
                stamp_ns=self.get_clock().now().nanoseconds,
            )
        )


def main(args: list[str] | None = None) -> int:
    return lifecycle.run_node('track_merge', TrackMergeNode, args)


if __name__ == '__main__':
    sys.exit(main())
