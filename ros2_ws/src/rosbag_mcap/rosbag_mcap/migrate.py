"""Replay of messages recorded with another definition of their type.

A bag keeps the full definition each topic was recorded with. When the installed type has
other fields (a field added in a later version of the interfaces, say), the recorded CDR
bytes no longer deserialize as the installed type, and a subscriber would drop every message.
``Migration`` decodes such a message with the recorded definition (``rosbags``, which parses
any ``ros2msg`` text) and builds the installed type from it, field by field by name: fields
the recording lacks keep the installed defaults, recorded fields the installed type no longer
has are dropped (and named, once, in :attr:`Migration.dropped`).

Only the field layout is compared: a bag whose definitions differ in comments only plays its
bytes as they are.
"""

from __future__ import annotations

import importlib
import re
from typing import Any

import numpy as np

from .definitions import SEPARATOR


class MigrationError(Exception):
    """The recorded definition cannot be decoded or mapped onto the installed type."""


def split_definitions(full_text: str, type_name: str) -> dict[str, str]:
    """{'pkg/msg/Type': its own text} for the main type and each ``MSG:`` section."""
    parts = full_text.split(f'\n{SEPARATOR}\n')
    out = {_normal(type_name): parts[0]}
    for part in parts[1:]:
        header, _, text = part.partition('\n')
        if not header.startswith('MSG: '):
            raise MigrationError(f'definition of {type_name}: section without MSG: line')
        out[_normal(header[5:].strip())] = text
    return out


def _normal(name: str) -> str:
    """'pkg/Type' and 'pkg/msg/Type' both as 'pkg/msg/Type'."""
    parts = name.split('/')
    return f'{parts[0]}/msg/{parts[-1]}' if len(parts) == 2 else name


def parse_definitions(full_text: str, type_name: str) -> dict[str, Any]:
    """rosbags type entries of the type and its dependencies, parsed from a full definition."""
    from rosbags.typesys import get_types_from_msg

    types: dict[str, Any] = {}
    for name, text in split_definitions(full_text, type_name).items():
        try:
            types.update(get_types_from_msg(text, name))
        except Exception as exc:  # noqa: BLE001 (the parser raises its own error types)
            raise MigrationError(
                f'cannot parse the recorded definition of {name}: {exc}'
            ) from None
    return types


def field_layout(full_text: str, type_name: str) -> dict[str, Any]:
    """Field names and types of the type and its dependencies, comments ignored."""
    types = parse_definitions(full_text, type_name)
    return {name: fields for name, (_consts, fields) in types.items()}


def needs_migration(recorded_text: str, installed_text: str, type_name: str) -> bool:
    """True when the two full definitions give ``type_name`` another field layout."""
    if not recorded_text or recorded_text == installed_text:
        return False
    return field_layout(recorded_text, type_name) != field_layout(installed_text, type_name)


class Migration:
    """Converts CDR bytes of ``type_name`` recorded with ``recorded_text`` into the
    installed type's CDR bytes."""

    def __init__(self, recorded_text: str, type_name: str, msg_type: type) -> None:
        from rosbags.typesys import Stores, get_typestore

        self._type_name = _normal(type_name)
        self._msg_type = msg_type
        self._store = get_typestore(Stores.EMPTY)
        types = parse_definitions(recorded_text, type_name)
        self._store.register(types)
        self.dropped: set[str] = set()

    def __call__(self, data: bytes) -> bytes:
        from rclpy.serialization import serialize_message

        try:
            recorded = self._store.deserialize_cdr(data, self._type_name)
        except Exception as exc:  # noqa: BLE001 (damaged payloads fail in many ways)
            raise MigrationError(f'cannot decode a recorded {self._type_name}: {exc}') from None
        return serialize_message(self._build(self._msg_type, recorded, self._type_name))

    def _build(self, msg_type: type, recorded: Any, path: str) -> Any:
        msg = msg_type()
        fields = msg_type.get_fields_and_field_types()
        for name in vars(recorded) if hasattr(recorded, '__dict__') else recorded.__slots__:
            if name not in fields:
                self.dropped.add(f'{path}.{name}')
        for name, ros_type in fields.items():
            if not hasattr(recorded, name):
                continue  # not recorded: the installed default stays
            value = getattr(recorded, name)
            element = _message_class(ros_type)
            if element is None:
                setattr(msg, name, value.tolist() if isinstance(value, np.ndarray) else value)
            elif ros_type.startswith('sequence<') or ros_type.endswith(']'):
                setattr(msg, name, [self._build(element, v, f'{path}.{name}') for v in value])
            else:
                setattr(msg, name, self._build(element, value, f'{path}.{name}'))
        return msg


_MESSAGE_FIELD = re.compile(r'^(?:sequence<)?([a-z][\w]*)/(\w+)(?:, \d+)?>?(?:\[\d*\])?$')


def _message_class(ros_type: str) -> type | None:
    """The message class of a field type like 'builtin_interfaces/Time' or
    'sequence<road_sensor_msgs/Track>'; None for primitive types and strings."""
    match = _MESSAGE_FIELD.match(ros_type)
    if match is None:
        return None
    package, name = match.groups()
    return getattr(importlib.import_module(f'{package}.msg'), name)
