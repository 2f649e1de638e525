"""Bags in rosbag2's MCAP layout, without ROS: writer, reader, metadata and QoS text.

A bag is a directory holding ``metadata.yaml`` (``rosbag2_bagfile_information`` version 9, as
rosbag2 Jazzy writes it) and ``<dirname>_0.mcap``. The MCAP file uses profile ``ros2``:
schemas ``ros2msg`` with the full definition text (see :mod:`rosbag_mcap.definitions`),
channels with message encoding ``cdr`` and metadata ``offered_qos_profiles`` (rosbag2's QoS
YAML) and ``topic_type_hash`` (``RIHS01_...``); payloads are the CDR bytes as received;
``log_time`` is the receive time [ns], ``publish_time`` the sender's source timestamp [ns].
Chunks are zstd-compressed (the mcap C++ writer's default, which rosbag2 uses) and indexed,
with a summary section, plus the ``rosbag2`` metadata record that rosbag2 writes on close.

Reading is in :mod:`rosbag_mcap.reader` (``BagReader``, also importable from here), repair of
unfinished or damaged files in :mod:`rosbag_mcap.mcapfile` and :mod:`rosbag_mcap.reindex`.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from mcap.writer import CompressionType, Writer

METADATA_FILE = 'metadata.yaml'
METADATA_VERSION = 9
ROS_DISTRO = 'jazzy'
PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'
LIBRARY = 'rosbag_mcap/0.1.0 (python mcap writer)'
DEFAULT_CHUNK_SIZE = 768 * 1024  # bytes, the mcap C++ writer's default (rosbag2's)
RESERVE_FILE = '.bag_recorder_reserve'
RESERVE_BYTES = 256 * 1024  # disk space held back to finish a bag when the disk fills up

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


class BagWriteError(BagError):
    """Writing the bag failed (e.g. the disk is full); nothing more can be written to it."""


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


# --------------------------------------------------------------------------- writer


@dataclass
class _WriterTopic:
    info: TopicInfo
    channel_id: int


class BagWriter:
    """Writes one bag directory. Not thread-safe: call from one thread (the node's executor).

    ``close()`` finishes the MCAP (summary, indexes, footer) and writes metadata.yaml; it is
    idempotent. ``flush()`` ends the current chunk so that a recording killed without a clean
    close keeps everything written up to the last flush readable.

    A failed write (a full disk, an I/O error) raises :class:`BagWriteError` and ends the
    recording: :attr:`failure` says why and later writes raise at once. ``close()`` then keeps
    what reached the disk: it cuts the MCAP after its last intact record, finishes it (summary,
    footer) and writes metadata.yaml, in the ``reserve`` bytes held back in a placeholder file
    from the start. It raises BagWriteError only if even that is impossible.
    """

    def __init__(
        self,
        directory: str | os.PathLike,
        *,
        compression: str = 'zstd',
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        custom_data: dict[str, str] | None = None,
        reserve: int = RESERVE_BYTES,
    ) -> None:
        self.directory = Path(directory)
        if self.directory.exists() and (
            not self.directory.is_dir() or any(self.directory.iterdir())
        ):
            raise BagError(f'{self.directory}: output exists and is not an empty directory')
        compressions = {
            'zstd': CompressionType.ZSTD,
            'lz4': CompressionType.LZ4,
            'none': CompressionType.NONE,
            '': CompressionType.NONE,
        }
        if compression not in compressions:
            raise BagError(f'unknown chunk compression {compression!r} (zstd, lz4, none)')
        self.directory.mkdir(parents=True, exist_ok=True)
        self.file_name = f'{self.directory.name}_0.mcap'
        self.path = self.directory / self.file_name
        self._custom_data = custom_data
        self._reserve = self.directory / RESERVE_FILE
        self.failure: str | None = None
        self._closed_info: dict | None = None
        try:
            with open(self._reserve, 'wb') as placeholder:
                placeholder.write(bytes(reserve))
        except OSError as exc:
            self._reserve.unlink(missing_ok=True)
            raise BagError(
                f'{self.directory}: cannot reserve {reserve} bytes to finish the bag: '
                f'{exc.strerror or exc}'
            ) from None
        self._stream = open(self.path, 'wb')  # noqa: SIM115 (closed in close())
        self._mcap = Writer(
            self._stream, chunk_size=chunk_size, compression=compressions[compression]
        )
        self._mcap.start(profile=PROFILE, library=LIBRARY)
        self._topics: dict[str, _WriterTopic] = {}
        self._schemas: dict[str, int] = {}
        self._first_ns: int | None = None
        self._last_ns: int | None = None
        self.message_count = 0
        self.closed = False

    @property
    def topics(self) -> dict[str, TopicInfo]:
        return {name: t.info for name, t in self._topics.items()}

    def has_topic(self, name: str) -> bool:
        return name in self._topics

    def add_topic(
        self,
        name: str,
        type_name: str,
        definition: str,
        offered_qos: Sequence[QosSpec] = (),
        type_hash: str = '',
    ) -> None:
        """Register a topic (one channel); its schema is shared by all topics of the type."""
        if name in self._topics:
            raise BagError(f'{self.path}: topic {name} added twice')
        self._check()
        try:
            self._add_topic(name, type_name, definition, offered_qos, type_hash)
        except OSError as exc:
            raise self._fail(exc) from None

    def _add_topic(
        self,
        name: str,
        type_name: str,
        definition: str,
        offered_qos: Sequence[QosSpec],
        type_hash: str,
    ) -> None:
        schema_id = self._schemas.get(type_name)
        if schema_id is None:
            schema_id = self._mcap.register_schema(
                name=type_name, encoding=SCHEMA_ENCODING, data=definition.encode('utf-8')
            )
            self._schemas[type_name] = schema_id
        info = TopicInfo(
            name=name, type=type_name, offered_qos=list(offered_qos), type_hash=type_hash
        )
        channel_id = self._mcap.register_channel(
            topic=name,
            message_encoding=MESSAGE_ENCODING,
            schema_id=schema_id,
            metadata={
                'offered_qos_profiles': qos_to_yaml(info.offered_qos),
                'topic_type_hash': type_hash,
            },
        )
        self._topics[name] = _WriterTopic(info, channel_id)

    def write(
        self,
        topic: str,
        data: bytes,
        log_time: int,
        publish_time: int | None = None,
        sequence: int = 0,
    ) -> None:
        """Append one serialized message (``log_time``/``publish_time`` in ns)."""
        entry = self._topics[topic]
        self._check()
        try:
            self._mcap.add_message(
                channel_id=entry.channel_id,
                log_time=log_time,
                data=data,
                publish_time=log_time if publish_time is None else publish_time,
                sequence=sequence & 0xFFFFFFFF,
            )
        except OSError as exc:
            raise self._fail(exc) from None
        entry.info.message_count += 1
        self.message_count += 1
        if self._first_ns is None or log_time < self._first_ns:
            self._first_ns = log_time
        if self._last_ns is None or log_time > self._last_ns:
            self._last_ns = log_time

    def flush(self) -> None:
        """End the current chunk and hand it to the operating system."""
        if self.closed or self.failure is not None:
            return
        try:
            self._mcap.flush()
        except OSError as exc:
            raise self._fail(exc) from None

    def _check(self) -> None:
        if self.failure is not None:
            raise BagWriteError(self.failure)
        if self.closed:
            raise BagWriteError(f'{self.path}: the bag is closed')

    def _fail(self, exc: OSError) -> BagWriteError:
        if self.failure is None:
            self.failure = f'{self.path}: writing failed: {exc.strerror or exc}'
        return BagWriteError(self.failure)

    def metadata(self) -> dict:
        start = self._first_ns or 0
        files = [
            {
                'path': self.file_name,
                'starting_time': {'nanoseconds_since_epoch': start},
                'duration': {'nanoseconds': (self._last_ns - start) if self._last_ns else 0},
                'message_count': self.message_count,
            }
        ]
        return metadata_dict(
            files=files,
            topics=[t.info for t in self._topics.values()],
            custom_data=self._custom_data,
        )

    def close(self) -> dict:
        """Finish the MCAP and write metadata.yaml; returns the metadata mapping.

        After a write failure the metadata describes what was kept (see the class).
        """
        info = self.metadata()
        if self.closed:
            return self._closed_info or info
        self.closed = True
        if self.failure is None:
            try:
                self._reserve.unlink(missing_ok=True)  # room for the summary
                # As rosbag2_storage_mcap: the BagMetadata mapping itself, without the root key.
                serialized = yaml.safe_dump(
                    info, sort_keys=False, default_flow_style=False, allow_unicode=True, width=1000
                )
                self._mcap.add_metadata('rosbag2', {'serialized_metadata': serialized})
                self._mcap.finish()
                self._stream.close()
                tmp = self.directory / (METADATA_FILE + '.tmp')
                tmp.write_text(dump_metadata(info), encoding='utf-8')
                tmp.replace(self.directory / METADATA_FILE)
                self._closed_info = info
                return info
            except OSError as exc:
                self._fail(exc)
        self._closed_info = self._keep_written_part()
        return self._closed_info

    def _keep_written_part(self) -> dict:
        """After a failed write: make what reached the disk a finished, readable bag."""
        try:
            self._stream.close()  # flushing the rest fails again on a full disk; it is closed
        except OSError:
            pass
        self._reserve.unlink(missing_ok=True)
        (self.directory / (METADATA_FILE + '.tmp')).unlink(missing_ok=True)
        from rosbag_mcap.reindex import repair_file, write_metadata  # needs the reader

        try:
            if self.path.stat().st_size < 16:  # not even the MCAP header reached the disk
                self._write_empty_mcap()
            result, _ = repair_file(self.path)
            return write_metadata(self.directory, [result])
        except (BagError, OSError) as exc:
            raise BagWriteError(
                f'{self.failure}; the bag could not be finished either ({exc}); free some '
                f'space, then run: bag_reindex {self.directory}'
            ) from None

    def _write_empty_mcap(self) -> None:
        with open(self.path, 'wb') as stream:
            writer = Writer(stream)
            writer.start(profile=PROFILE, library=LIBRARY)
            writer.finish()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def default_bag_name(now: float | None = None) -> str:
    """'rosbag2_YYYY_MM_DD-HH_MM_SS' (rosbag2's default bag directory name), local time."""
    return time.strftime('rosbag2_%Y_%m_%d-%H_%M_%S', time.localtime(now))


def __getattr__(name: str):
    """The reader lives in :mod:`rosbag_mcap.reader`; ``storage.BagReader`` still works."""
    if name in ('BagReader', 'BagMessage'):
        from rosbag_mcap import reader

        return getattr(reader, name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
