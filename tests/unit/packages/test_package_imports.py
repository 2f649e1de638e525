"""Packages point one way, and mlkm_core and rosbag_mcap have no import cycle.

Read from the sources (ast), not by importing them, so that every import counts: the ones at
module level, inside functions (deferred) and under ``if TYPE_CHECKING:``. Dynamic imports
(``importlib.import_module(name)``) are not seen.

1. Direction: every import of a first-party package (one of ``ros2_ws/src``) by a module of
   another must be an arrow of ``ALLOWED``; a package.xml may declare only those arrows too.
   The product never depends on its experiments and benchmarks (``mlkm_experiments``).
2. No circle: the module import graph of each package of ``ACYCLIC`` (relative imports
   resolved; ``from p import m`` is an edge to the module ``p.m`` when there is one) has no
   cycle.
3. scripts/ (the demo and the replay) use the product only: no ``mlkm_experiments``, no
   private module or name (a leading underscore).

The first tests of each part feed the checkers synthetic input, to show they can fail.
"""

from __future__ import annotations

import ast
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
SRC = REPO / 'ros2_ws' / 'src'
SCRIPTS = REPO / 'scripts'

#: package -> the first-party packages its modules may import (``road_sensor_msgs`` is the
#: generated message package). Keep it strict: an arrow is here because the code needs it.
PRODUCT: dict[str, frozenset[str]] = {
    'road_sensor_msgs': frozenset(),
    'mlkm_core': frozenset(),
    'mlkm_sumo': frozenset({'mlkm_core'}),
    'mlkm_ros': frozenset({'mlkm_core', 'road_sensor_msgs'}),
    'road_sensors': frozenset({'mlkm_core', 'mlkm_sumo', 'mlkm_ros', 'road_sensor_msgs'}),
    # rosbag_mcap: its bag reader, for `mlkm plot` on a bag (timespace_bag.py)
    'mlkm_assoc': frozenset({'mlkm_core', 'mlkm_ros', 'road_sensor_msgs', 'rosbag_mcap'}),
    'rosbag_mcap': frozenset({'mlkm_ros'}),
}
#: The experiments and benchmarks may use the whole product; nothing may use them.
ALLOWED: dict[str, frozenset[str]] = {**PRODUCT, 'mlkm_experiments': frozenset(PRODUCT)}

#: Packages whose module graph must have no cycle.
ACYCLIC = ('mlkm_core', 'rosbag_mcap')


# --- reading the imports ---------------------------------------------------------------------


@dataclass(frozen=True)
class Import:
    path: str  # file, relative to the repository when it is in it
    line: int
    importer: str  # module name of the file
    target: str  # absolute module name imported (for ``from p import n``: p.n if a module)
    text: str  # the statement, for messages


def module_name(path: Path, root: Path) -> str:
    """``a/b/c.py`` -> ``a.b.c``; ``a/b/__init__.py`` -> ``a.b`` (relative to ``root``)."""
    parts = list(path.relative_to(root).with_suffix('').parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


def imports_of(
    source: str, module: str, is_package: bool, path: str, modules: Iterable[str] = ()
) -> list[Import]:
    """Every import statement of ``source`` (module ``module``), wherever it stands, with
    relative imports resolved. ``from p import n`` targets ``p.n`` when that is one of
    ``modules``, else ``p``."""
    known = set(modules)
    package = module if is_package else module.rpartition('.')[0]
    found = []
    for node in ast.walk(ast.parse(source, path)):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split('.') if package else []
                if node.level - 1 > len(base):
                    raise ValueError(f'{path}:{node.lineno}: relative import beyond the top')
                base = base[: len(base) - (node.level - 1)]
                origin = '.'.join(base + ([node.module] if node.module else []))
            else:
                origin = node.module or ''
            targets = [
                f'{origin}.{a.name}' if f'{origin}.{a.name}' in known else origin
                for a in node.names
            ]
        else:
            continue
        text = ast.get_source_segment(source, node) or ''
        text = ' '.join(text.split())
        found += [Import(path, node.lineno, module, t, text) for t in dict.fromkeys(targets)]
    return found


def package_dirs() -> dict[str, Path]:
    """ROS package name -> its directory under ros2_ws/src."""
    return {p.parent.name: p.parent for p in sorted(SRC.glob('*/package.xml'))}


def python_files(package_dir: Path) -> list[Path]:
    return sorted(
        p
        for p in package_dir.rglob('*.py')
        if '__pycache__' not in p.parts and p.name != 'setup.py'
    )


def _rel(path: Path) -> str:
    try:
        return str(path.relative_to(REPO))
    except ValueError:
        return str(path)


def package_imports(package_dir: Path) -> list[Import]:
    """Every import of every module of the package (its Python files but setup.py)."""
    files = python_files(package_dir)
    modules = {module_name(f, package_dir) for f in files}
    out = []
    for f in files:
        out += imports_of(
            f.read_text(),
            module_name(f, package_dir),
            f.name == '__init__.py',
            _rel(f),
            modules,
        )
    return out


# --- 1. direction ------------------------------------------------------------------------------


def forbidden_imports(
    package: str, imports: Iterable[Import], allowed: dict[str, frozenset[str]]
) -> list[str]:
    """One message per import of ``package`` naming a first-party package it may not use."""
    problems = []
    for imp in imports:
        top = imp.target.split('.')[0]
        if top == package or top not in allowed:
            continue  # itself, the standard library or a third-party package
        if top not in allowed.get(package, frozenset()):
            may = ', '.join(sorted(allowed.get(package, ()))) or 'no first-party package'
            problems.append(
                f'{imp.path}:{imp.line}: forbidden arrow {package} -> {top} '
                f'({imp.text}); {package} may import {may}'
            )
    return problems


def test_forbidden_imports_names_file_line_and_arrow():
    src = (
        'import os\n'
        'from mlkm_core.types import Layout\n'
        'def f():\n'
        '    from mlkm_experiments import bench\n'
        'if TYPE_CHECKING:\n'
        '    import mlkm_sumo.scenarios\n'
    )
    imps = imports_of(src, 'mlkm_assoc.cli', False, 'x/cli.py')
    problems = forbidden_imports('mlkm_assoc', imps, ALLOWED)
    assert len(problems) == 2, problems
    assert problems[0].startswith('x/cli.py:4: forbidden arrow mlkm_assoc -> mlkm_experiments')
    assert problems[1].startswith('x/cli.py:6: forbidden arrow mlkm_assoc -> mlkm_sumo')
    assert 'mlkm_assoc may import mlkm_core, mlkm_ros, road_sensor_msgs' in problems[0]
    assert forbidden_imports('mlkm_experiments', imps, ALLOWED) == []


def test_relative_imports_are_resolved():
    src = 'from . import kalman\nfrom ..types import Layout\nfrom .base import X\n'
    imps = imports_of(
        src, 'mlkm_core.associators.motion', False, 'm.py', {'mlkm_core.associators.kalman'}
    )
    assert [i.target for i in imps] == [
        'mlkm_core.associators.kalman',
        'mlkm_core.types',
        'mlkm_core.associators.base',
    ]
    imps = imports_of('from .motion import M\n', 'mlkm_core.associators', True, 'i.py')
    assert [i.target for i in imps] == ['mlkm_core.associators.motion']


def test_every_package_is_in_the_table():
    assert set(package_dirs()) == set(ALLOWED), (
        'the packages of ros2_ws/src and ALLOWED differ: place a new package in the table '
        f'(packages: {sorted(package_dirs())}, table: {sorted(ALLOWED)})'
    )


def test_packages_import_only_what_the_table_allows():
    problems = []
    for package, path in package_dirs().items():
        problems += forbidden_imports(package, package_imports(path), ALLOWED)
    assert not problems, 'imports against the package direction:\n' + '\n'.join(problems)


def declared_dependencies(package_xml: Path) -> list[tuple[int, str]]:
    """(line, name) of each <depend>, <exec_depend> and <build_depend> of a package.xml."""
    lines = package_xml.read_text().splitlines()
    out = []
    for el in ET.parse(package_xml).getroot():
        if el.tag in ('depend', 'exec_depend', 'build_depend') and el.text:
            name = el.text.strip()
            line = next((i for i, t in enumerate(lines, 1) if f'>{name}<' in t), 0)
            out.append((line, name))
    return out


def test_package_xml_declares_only_allowed_arrows():
    problems = []
    for package, path in package_dirs().items():
        for line, dep in declared_dependencies(path / 'package.xml'):
            if dep in ALLOWED and dep != package and dep not in ALLOWED[package]:
                problems.append(
                    f'{_rel(path / "package.xml")}:{line}: forbidden arrow {package} -> {dep}'
                )
    assert not problems, 'package.xml against the package direction:\n' + '\n'.join(problems)


def test_package_xml_declares_every_first_party_import():
    problems = []
    for package, path in package_dirs().items():
        declared = {d for _, d in declared_dependencies(path / 'package.xml')}
        used = {}
        for imp in package_imports(path):
            top = imp.target.split('.')[0]
            if top in ALLOWED and top != package:
                used.setdefault(top, imp)
        problems += [
            f'{imp.path}:{imp.line}: {package} imports {top} ({imp.text}) but its '
            'package.xml does not declare it'
            for top, imp in sorted(used.items())
            if top not in declared
        ]
    assert not problems, '\n'.join(problems)


# --- 2. no circle --------------------------------------------------------------------------------


Graph = dict[str, dict[str, Import]]


def import_graph(imports: Iterable[Import], modules: Iterable[str]) -> Graph:
    """module -> {imported module: the first import making that edge}, within ``modules``."""
    nodes = set(modules)
    graph: Graph = {m: {} for m in sorted(nodes)}
    for imp in imports:
        if imp.importer in nodes and imp.target in nodes and imp.target != imp.importer:
            graph[imp.importer].setdefault(imp.target, imp)
    return graph


def components(graph: dict[str, Iterable[str]]) -> list[list[str]]:
    """The strongly connected components of ``graph`` (Tarjan), each a list of nodes."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def strongconnect(v: str) -> None:  # Tarjan, iteratively
        work = [(v, iter(sorted(graph.get(v, ()))))]
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        while work:
            node, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                    break
                if w in on_stack:
                    low[node] = min(low[node], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == node:
                            break
                    found.append(comp)

    for v in sorted(graph):
        if v not in index:
            strongconnect(v)
    return found


def find_cycles(graph: dict[str, Iterable[str]]) -> list[list[str]]:
    """One cycle ``[a, b, ..., a]`` per strongly connected component that has one."""
    cycles = []
    for comp in components(graph):
        members = set(comp)
        start = min(comp)
        if len(comp) == 1 and start not in graph.get(start, ()):
            continue
        cycles.append(_cycle_through(graph, start, members))
    return sorted(cycles)


def _cycle_through(graph: dict[str, Iterable[str]], start: str, members: set[str]) -> list[str]:
    """A shortest path start -> ... -> start inside one strongly connected component."""
    parent: dict[str, str] = {}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph.get(v, ())):
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(parent[path[-1]])
                    return [*reversed(path), start]
                if w in members and w not in parent:
                    parent[w] = v
                    nxt.append(w)
        frontier = nxt
    raise AssertionError(f'no cycle through {start}')  # pragma: no cover


def describe_cycle(cycle: list[str], graph: Graph) -> str:
    """The cycle, the import making each arrow, and every module caught in it."""
    steps = [
        f'  {(imp := graph[a][b]).path}:{imp.line}: {imp.text}' for a, b in zip(cycle, cycle[1:])
    ]
    caught = next((c for c in components(graph) if cycle[0] in c), [])
    return (
        'import cycle '
        + ' -> '.join(cycle)
        + ':\n'
        + '\n'.join(steps)
        + f'\n  (modules on a cycle with it: {", ".join(sorted(caught))})'
    )


def test_find_cycles_names_the_cycle():
    graph = {'a': {'b'}, 'b': {'c'}, 'c': {'a', 'd'}, 'd': set(), 'e': {'e'}, 'f': {'a'}}
    assert find_cycles(graph) == [['a', 'b', 'c', 'a'], ['e', 'e']]
    assert find_cycles({'a': {'b'}, 'b': set()}) == []


def test_a_deferred_and_a_type_checking_import_make_a_cycle():
    sources = {
        'p.motion': (
            'from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .lanes import L\n'
        ),
        'p.lanes': 'def f():\n    from p import motion\n',
    }
    modules = set(sources) | {'p'}
    imports = [i for m, s in sources.items() for i in imports_of(s, m, False, f'{m}.py', modules)]
    graph = import_graph(imports, modules)
    cycles = find_cycles(graph)
    assert cycles == [['p.lanes', 'p.motion', 'p.lanes']]
    message = describe_cycle(cycles[0], graph)
    assert 'p.lanes.py:2: from p import motion' in message
    assert 'p.motion.py:3: from .lanes import L' in message


@pytest.mark.parametrize('package', ACYCLIC)
def test_no_import_cycle(package):
    path = package_dirs()[package]
    modules = {module_name(f, path) for f in python_files(path)}
    assert f'{package}' in modules, modules
    graph = import_graph(package_imports(path), modules)
    cycles = find_cycles(graph)
    assert not cycles, '\n'.join(describe_cycle(c, graph) for c in cycles)


# --- 3. scripts ---------------------------------------------------------------------------------


def private_or_experimental(imports: Iterable[Import]) -> Iterator[str]:
    for imp in imports:
        parts = imp.target.split('.')
        if parts[0] not in ALLOWED:
            continue
        if parts[0] not in PRODUCT:
            yield f'{imp.path}:{imp.line}: scripts use the product only ({imp.text})'
        elif any(p.startswith('_') for p in parts):
            yield f'{imp.path}:{imp.line}: private module ({imp.text})'


def private_names(source: str, path: str) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(source, path)):
        if (
            isinstance(node, ast.ImportFrom)
            and node.level == 0
            and (node.module or '').split('.')[0] in PRODUCT
        ):
            out += [
                f'{path}:{node.lineno}: private name {a.name} of {node.module}'
                for a in node.names
                if a.name.startswith('_')
            ]
    return out


def test_script_checker_finds_experiments_and_private_names():
    src = 'from mlkm_experiments.bench import main\nfrom mlkm_ros.processes import _killpg\n'
    imps = imports_of(src, 'demo', False, 'demo.py')
    assert list(private_or_experimental(imps)) == [
        'demo.py:1: scripts use the product only (from mlkm_experiments.bench import main)'
    ]
    assert private_names(src, 'demo.py') == [
        'demo.py:2: private name _killpg of mlkm_ros.processes'
    ]


def test_scripts_use_only_public_product_modules():
    problems = []
    for f in sorted(SCRIPTS.glob('*.py')):
        src = f.read_text()
        problems += private_or_experimental(imports_of(src, f.stem, False, _rel(f)))
        problems += private_names(src, _rel(f))
    assert not problems, '\n'.join(problems)
