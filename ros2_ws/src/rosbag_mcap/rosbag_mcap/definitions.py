"""Full ``ros2msg`` message definitions, assembled the way rosbag2_storage_mcap does it.

The schema data of a channel is the top-level ``.msg`` text followed, for every type it
depends on (recursively, depth first, each type once, dependencies of one file in sorted
order), by a line of 80 ``=``, a line ``MSG: pkg/Type`` and that type's ``.msg`` text.

ROS-free: the ``.msg`` files are found through ``AMENT_PREFIX_PATH`` (``<prefix>/share/<pkg>/
msg/<Type>.msg``), the Python prefix, and the ``share`` directory next to the Python package of
the interface (colcon install and pip-installed wheels both lay it out that way).
"""

from __future__ import annotations

import importlib.util
import os
import re
import sys
from collections.abc import Callable, Iterable
from pathlib import Path

SEPARATOR = '=' * 80

# Type names 'pkg/Type' or 'pkg/msg/Type' (also srv/ and action/ for service and action topics).
_TYPENAME_RE = re.compile(
    r'^([a-zA-Z][a-zA-Z0-9_]*)/(?:(msg|srv|action)/)?([a-zA-Z][a-zA-Z0-9_]*)$'
)
# The field type at the start of a .msg line ('pkg/Type' in 'pkg/Type[] name').
_FIELD_TYPE_RE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
PRIMITIVE_TYPES = frozenset(
    {
        'bool',
        'byte',
        'char',
        'float32',
        'float64',
        'int8',
        'uint8',
        'int16',
        'uint16',
        'int32',
        'uint32',
        'int64',
        'uint64',
        'string',
        'wstring',
    }
)

MsgLookup = Callable[[str, str, str], str]
"""(package, namespace 'msg', type name) -> .msg text; raises DefinitionNotFoundError."""


class DefinitionNotFoundError(LookupError):
    """No .msg file could be found for a type."""


def split_type_name(type_name: str) -> tuple[str, str, str]:
    """'pkg/msg/Type' or 'pkg/Type' -> ('pkg', 'msg', 'Type'); ValueError otherwise."""
    match = _TYPENAME_RE.match(type_name)
    if match is None:
        raise ValueError(f'type name {type_name!r} is not of the form pkg/msg/Type')
    return match.group(1), match.group(2) or 'msg', match.group(3)


def msg_dependencies(text: str, package: str) -> list[str]:
    """Non-primitive field types of one .msg text as 'pkg/Type', sorted, without repeats."""
    deps: set[str] = set()
    for match in _FIELD_TYPE_RE.finditer(text):
        field_type = match.group(1)
        if field_type in PRIMITIVE_TYPES:
            continue
        deps.add(field_type if '/' in field_type else f'{package}/{field_type}')
    return sorted(deps)


def _search_prefixes(package: str) -> list[Path]:
    prefixes = [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    prefixes.append(Path(sys.prefix))
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        spec = None
    if spec is not None and spec.origin:
        # <prefix>/lib/pythonX.Y/site-packages/<pkg>/__init__.py -> <prefix>
        prefixes.extend(Path(spec.origin).resolve().parents[1:6])
    return prefixes


def find_msg_file(package: str, namespace: str, name: str) -> Path:
    """Path of ``share/<package>/<namespace>/<name>.msg`` under the known prefixes."""
    for prefix in _search_prefixes(package):
        candidate = prefix / 'share' / package / namespace / f'{name}.msg'
        if candidate.is_file():
            return candidate
    raise DefinitionNotFoundError(
        f'no {package}/{namespace}/{name}.msg under AMENT_PREFIX_PATH, {sys.prefix} '
        f'or next to the Python package {package!r}'
    )


def read_msg_file(package: str, namespace: str, name: str) -> str:
    """Default MsgLookup: the text of the installed .msg file."""
    return find_msg_file(package, namespace, name).read_text(encoding='utf-8')


class DefinitionCache:
    """Assembles and caches full message definitions (thread-compatible, not thread-safe)."""

    def __init__(self, lookup: MsgLookup = read_msg_file, max_depth: int = 50) -> None:
        self._lookup = lookup
        self._max_depth = max_depth
        self._texts: dict[tuple[str, str, str], str] = {}
        self._full: dict[str, str] = {}

    def _text(self, type_name: str) -> tuple[str, str]:
        package, namespace, name = split_type_name(type_name)
        key = (package, namespace, name)
        if key not in self._texts:
            self._texts[key] = self._lookup(package, namespace, name)
        return self._texts[key], package

    def full_text(self, type_name: str) -> str:
        """The concatenated definition of ``type_name`` ('pkg/msg/Type')."""
        if type_name in self._full:
            return self._full[type_name]
        seen: set[str] = set()

        def append(dep_name: str, depth: int) -> str:
            if depth <= 0:
                raise DefinitionNotFoundError(
                    f'definition of {type_name} nests deeper than {self._max_depth} levels'
                )
            text, package = self._text(dep_name)
            parts = [text]
            for dep in msg_dependencies(text, package):
                if dep not in seen:
                    seen.add(dep)
                    parts.append(f'\n{SEPARATOR}\nMSG: {dep}\n')
                    parts.append(append(dep, depth - 1))
            return ''.join(parts)

        full = append(type_name, self._max_depth)
        self._full[type_name] = full
        return full


def dependency_names(full_text: str) -> Iterable[str]:
    """The 'pkg/Type' names of the ``MSG:`` sections of a full definition."""
    return re.findall(r'^MSG: (\S+)$', full_text, flags=re.MULTILINE)
