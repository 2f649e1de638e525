"""Bag metadata without ROS: the ``metadata.yaml`` mapping (``rosbag2_bagfile_information``
version 9, as rosbag2 Jazzy writes it; versions up to 10 are read), its topics, and the
offered-QoS YAML text rosbag2 stores per topic (written as Jazzy writes it, read from every
version, and turned into the QoS a player offers). :mod:`rosbag_mcap.storage` writes bags
with it, :mod:`rosbag_mcap.reader` reads them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

METADATA_FILE = 'metadata.yaml'
#: disk space the recorder holds back in the bag directory to finish a bag on a full disk
RESERVE_FILE = '.bag_recorder_reserve'
METADATA_VERSION = 9
ROS_DISTRO = 'jazzy'
PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'

INFINITE_NS = 9223372036854775807  # RMW_DURATION_INFINITE = {9223372036 s, 854775807 ns}
_FOXY_INFINITES = {(0x7FFFFFFF, 0xFFFFFFFF), (0x7FFFFFFF, 0x7FFFFFFF)}

# Enum values as rosbag2 wrote them up to metadata version 8 (rmw enum integers).
_HISTORY = ('system_default', 'keep_last', 'keep_all', 'unknown')
_RELIABILITY = ('system_default', 'reliable', 'best_effort', 'unknown', 'best_available')
_DURABILITY = ('system_default', 'transient_local', 'volatile', 'unknown', 'best_available')
_LIVELINESS = (
    'system_default',
    'automatic',
    'manual_by_node',
    'manual_by_topic',
    'unknown',
    'best_available',
)


class BagError(Exception):
    """A bag cannot be opened or read; the message names the file and the reason."""


# --------------------------------------------------------------------------- QoS text


@dataclass(frozen=True)
class QosSpec:
    """One offered QoS profile, in rmw terms; durations in ns (INFINITE_NS = infinite)."""

    history: str = 'keep_last'
    depth: int = 10
    reliability: str = 'reliable'
    durability: str = 'volatile'
    deadline: int = 0
    lifespan: int = 0
    liveliness: str = 'system_default'
    liveliness_lease_duration: int = 0
    avoid_ros_namespace_conventions: bool = False


def _time_text(ns: int, indent: str) -> str:
    return f'\n{indent}  sec: {ns // 1_000_000_000}\n{indent}  nsec: {ns % 1_000_000_000}'


def qos_to_yaml(profiles: Sequence[QosSpec]) -> str:
    """rosbag2 Jazzy's ``offered_qos_profiles`` string (yaml-cpp block style, v9 enum names)."""
    if not profiles:
        return '[]'
    items = []
    for p in profiles:
        items.append(
            f'- history: {p.history}\n'
            f'  depth: {p.depth}\n'
            f'  reliability: {p.reliability}\n'
            f'  durability: {p.durability}\n'
            f'  deadline:{_time_text(p.deadline, "  ")}\n'
            f'  lifespan:{_time_text(p.lifespan, "  ")}\n'
            f'  liveliness: {p.liveliness}\n'
            f'  liveliness_lease_duration:{_time_text(p.liveliness_lease_duration, "  ")}\n'
            f'  avoid_ros_namespace_conventions: {"true" if p.avoid_ros_namespace_conventions else "false"}'  # noqa: E501
        )
    return '\n'.join(items)


def _enum(value: object, names: tuple[str, ...]) -> str:
    if isinstance(value, bool):
        raise ValueError(f'bad QoS policy value {value!r}')
    if isinstance(value, int):
        return names[value] if 0 <= value < len(names) else 'unknown'
    text = str(value).lower()
    return text if text in names else 'unknown'


def _time_ns(value: object) -> int:
    if not isinstance(value, dict):
        raise ValueError(f'bad QoS duration {value!r}')
    sec, nsec = int(value.get('sec', 0)), int(value.get('nsec', 0))
    if (sec, nsec) in _FOXY_INFINITES:
        return INFINITE_NS
    return min(sec * 1_000_000_000 + nsec, INFINITE_NS)


def parse_qos(text: str | list | None) -> list[QosSpec]:
    """Parse ``offered_qos_profiles`` (v4-v8 integers, v9 names; string or list); ValueError."""
    if text is None or text == '':
        return []
    data = yaml.safe_load(text) if isinstance(text, str) else text
    if data is None:
        return []
    if not isinstance(data, list):
        raise ValueError('offered_qos_profiles is not a list')
    out = []
    for item in data:
        if not isinstance(item, dict):
            raise ValueError('offered_qos_profiles entry is not a mapping')
        out.append(
            QosSpec(
                history=_enum(item.get('history', 'unknown'), _HISTORY),
                depth=int(item.get('depth', 0)),
                reliability=_enum(item.get('reliability', 'unknown'), _RELIABILITY),
                durability=_enum(item.get('durability', 'unknown'), _DURABILITY),
                deadline=_time_ns(item.get('deadline', {})),
                lifespan=_time_ns(item.get('lifespan', {})),
                liveliness=_enum(item.get('liveliness', 'unknown'), _LIVELINESS),
                liveliness_lease_duration=_time_ns(item.get('liveliness_lease_duration', {})),
                avoid_ros_namespace_conventions=bool(
                    item.get('avoid_ros_namespace_conventions', False)
                ),
            )
        )
    return out


def replay_qos(
    profiles: Sequence[QosSpec], message_count: int = 1, max_latched_depth: int = 1000
) -> QosSpec:
    """The profile to offer when replaying, from the recorded offers (rosbag2's rule).

    Reliable only if every recorded publisher was reliable, transient_local only if every one
    was (so latched topics stay latched). Volatile topics get history keep_all, so a fast
    replay into a slow subscriber drops nothing. Transient_local topics keep the last
    ``depth`` messages: the recorded depth when the recording knew it, raised to the topic's
    message count in the bag (at most ``max_latched_depth``) so that a fast replay cannot
    overwrite a latched message before it is delivered, and late subscribers get the
    topic's whole history (remote endpoints report depth 0 / history unknown).
    """
    if not profiles:
        return QosSpec()
    reliable = all(p.reliability == 'reliable' for p in profiles)
    latched = all(p.durability == 'transient_local' for p in profiles)
    if latched:
        known = sum(p.depth for p in profiles if p.history == 'keep_last' and p.depth > 0)
        depth = max(known, min(message_count, max_latched_depth), 1)
        history = 'keep_last'
    else:
        depth, history = 0, 'keep_all'
    return QosSpec(
        history=history,
        depth=depth,
        reliability='reliable' if reliable else 'best_effort',
        durability='transient_local' if latched else 'volatile',
        deadline=0,
        lifespan=0,
        liveliness='system_default',
        liveliness_lease_duration=0,
    )


# --------------------------------------------------------------------------- metadata


@dataclass
class TopicInfo:
    """One topic of a bag."""

    name: str
    type: str
    offered_qos: list[QosSpec] = field(default_factory=list)
    type_hash: str = ''
    message_count: int = 0
    serialization_format: str = MESSAGE_ENCODING


def metadata_dict(
    *,
    files: Sequence[dict],
    topics: Sequence[TopicInfo],
    custom_data: dict[str, str] | None = None,
) -> dict:
    """The ``rosbag2_bagfile_information`` mapping (rosbag2 field names and order)."""
    starts = [f['starting_time']['nanoseconds_since_epoch'] for f in files if f['message_count']]
    ends = [
        f['starting_time']['nanoseconds_since_epoch'] + f['duration']['nanoseconds']
        for f in files
        if f['message_count']
    ]
    start = min(starts) if starts else 0
    return {
        'version': METADATA_VERSION,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': (max(ends) - start) if ends else 0},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(f['message_count'] for f in files),
        'topics_with_message_count': [
            {
                'topic_metadata': {
                    'name': t.name,
                    'type': t.type,
                    'serialization_format': t.serialization_format,
                    'offered_qos_profiles': qos_to_yaml(t.offered_qos),
                    'type_description_hash': t.type_hash,
                },
                'message_count': t.message_count,
            }
            for t in topics
        ],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [f['path'] for f in files],
        'files': list(files),
        'custom_data': dict(custom_data) if custom_data else None,
        'ros_distro': ROS_DISTRO,
    }


def dump_metadata(info: dict) -> str:
    """YAML text of metadata.yaml for a ``rosbag2_bagfile_information`` mapping."""
    return yaml.safe_dump(
        {'rosbag2_bagfile_information': info},
        sort_keys=False,
        default_flow_style=False,
        allow_unicode=True,
        width=1000,
    )


def load_metadata(path: Path) -> dict:
    """The ``rosbag2_bagfile_information`` mapping of a metadata.yaml; BagError if unusable."""
    try:
        data = yaml.safe_load(path.read_text(encoding='utf-8'))
        info = data['rosbag2_bagfile_information']
        version = int(info['version'])
        if not isinstance(info['relative_file_paths'], list):
            raise TypeError('relative_file_paths is not a list')
    except OSError as exc:
        raise BagError(f'{path}: cannot read bag metadata: {exc.strerror or exc}') from None
    except yaml.YAMLError as exc:
        raise BagError(f'{path}: bag metadata is not valid YAML: {exc}') from None
    except (KeyError, TypeError, ValueError) as exc:
        raise BagError(f'{path}: not rosbag2 bag metadata ({type(exc).__name__}: {exc})') from None
    if version > 10:
        raise BagError(f'{path}: bag metadata version {version} is newer than supported (10)')
    return info
