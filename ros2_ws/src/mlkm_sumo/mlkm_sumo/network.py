"""SUMO binaries, scenario sources and the network cache.

Every network is built from the plain-text sources kept in the repository (``*.nod.xml``,
``*.edg.xml``, optional ``*.con.xml``) by SUMO's own ``netconvert``, on first use, into a cache
directory named after a hash of the sources and the netconvert version:
``$MLKM_SUMO_CACHE`` or ``$XDG_CACHE_HOME/mlkm_sumo`` (default ``~/.cache/mlkm_sumo``), or a
directory given by the caller. Nothing is downloaded.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path


class SumoError(RuntimeError):
    """A scenario, network, layout or SUMO run problem; the message says what and why."""


#: netconvert options of every build (part of the cache key).
NETCONVERT_OPTIONS = (
    '--no-turnarounds',
    'true',
    '--offset.disable-normalization',
    'true',
    '--no-warnings',
    'true',
)
_PACKAGE = 'mlkm_sumo'


def sumo_home() -> Path:
    """SUMO_HOME of the ``eclipse-sumo`` Python package (binaries in ``bin/``)."""
    try:
        import sumo
    except ImportError:
        raise SumoError(
            'the eclipse-sumo package is not installed (run make setup; it is pinned in '
            'requirements.txt)'
        ) from None
    return Path(sumo.SUMO_HOME)


def binary(name: str) -> Path:
    """Path of a SUMO executable (``sumo``, ``netconvert``) shipped by ``eclipse-sumo``."""
    path = sumo_home() / 'bin' / name
    if not (path.is_file() and os.access(path, os.X_OK)):
        raise SumoError(f'SUMO executable {name!r} not found at {path}')
    return path


def sumo_env() -> dict[str, str]:
    """Environment for SUMO processes: SUMO_HOME set so that SUMO finds its data files."""
    return {**os.environ, 'SUMO_HOME': str(sumo_home())}


def scenarios_root() -> Path:
    """Directory of the scenario sources: ``$MLKM_SUMO_SCENARIOS``, the package source tree
    (development and symlink installs) or the installed ``share/mlkm_sumo/scenarios``."""
    candidates = []
    if os.environ.get('MLKM_SUMO_SCENARIOS'):
        candidates.append(Path(os.environ['MLKM_SUMO_SCENARIOS']))
    here = Path(__file__).resolve().parent
    candidates.append(here.parent / 'scenarios')
    for parent in here.parents:  # <prefix>/lib/python3.X/site-packages/mlkm_sumo
        candidates.append(parent / 'share' / _PACKAGE / 'scenarios')
    for c in candidates:
        if (c / 'common').is_dir():
            return c
    raise SumoError(f'scenario sources not found; looked in {", ".join(map(str, candidates))}')


@dataclass(frozen=True)
class ScenarioFiles:
    """Sources of one scenario and where its built network lives."""

    name: str
    nodes: Path
    edges: Path
    connections: Path | None
    routes: Path  # the routeDistribution "demand"
    vtypes: Path  # the vTypeDistribution "mix"

    def sources(self) -> list[Path]:
        return [p for p in (self.nodes, self.edges, self.connections) if p is not None]


def scenario_files(name: str) -> ScenarioFiles:
    root = scenarios_root()
    d = root / name
    con = d / f'{name}.con.xml'
    files = ScenarioFiles(
        name,
        d / f'{name}.nod.xml',
        d / f'{name}.edg.xml',
        con if con.is_file() else None,
        d / f'{name}.rou.xml',
        root / 'common' / 'vtypes.add.xml',
    )
    missing = [
        str(p) for p in (files.nodes, files.edges, files.routes, files.vtypes) if not p.is_file()
    ]
    if missing:
        raise SumoError(f'scenario {name!r}: missing source file(s) {", ".join(missing)}')
    return files


def default_cache_dir() -> Path:
    if os.environ.get('MLKM_SUMO_CACHE'):
        return Path(os.environ['MLKM_SUMO_CACHE'])
    base = os.environ.get('XDG_CACHE_HOME') or str(Path.home() / '.cache')
    return Path(base) / _PACKAGE


def _netconvert_version(exe: Path) -> str:
    out = subprocess.run(
        [str(exe), '--version'], capture_output=True, text=True, env=sumo_env(), timeout=60
    )
    return out.stdout.splitlines()[0] if out.stdout else ''


def network_key(files: ScenarioFiles, exe: Path) -> str:
    h = hashlib.sha256()
    h.update(_netconvert_version(exe).encode())
    h.update(' '.join(NETCONVERT_OPTIONS).encode())
    for p in files.sources():
        h.update(p.name.encode() + b'\0' + p.read_bytes() + b'\0')
    return h.hexdigest()[:16]


def build_network(files: ScenarioFiles, cache_dir: str | Path | None = None) -> Path:
    """The ``.net.xml`` of a scenario: from the cache, or built now by netconvert.

    The build writes into a temporary directory next to the cache entry and renames it into
    place, so that concurrent first uses and interrupted builds never leave a partial network.
    """
    exe = binary('netconvert')
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    entry = cache / f'{files.name}-{network_key(files, exe)}'
    net = entry / f'{files.name}.net.xml'
    if net.is_file():
        return net
    try:
        cache.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(dir=cache, prefix=f'.{files.name}-'))
    except OSError as exc:
        raise SumoError(f'cannot create the network cache {cache}: {exc.strerror}') from None
    try:
        cmd = [
            str(exe),
            '--node-files',
            str(files.nodes),
            '--edge-files',
            str(files.edges),
            *(['--connection-files', str(files.connections)] if files.connections else []),
            *NETCONVERT_OPTIONS,
            '--output-file',
            str(tmp / net.name),
        ]
        try:
            out = subprocess.run(cmd, capture_output=True, text=True, env=sumo_env(), timeout=300)
        except subprocess.TimeoutExpired:
            raise SumoError(f'netconvert for scenario {files.name!r} timed out') from None
        if out.returncode != 0 or not (tmp / net.name).is_file():
            detail = (out.stderr or out.stdout).strip()[-2000:]
            raise SumoError(
                f'netconvert failed for scenario {files.name!r} (exit {out.returncode}): {detail}'
            )
        try:
            os.replace(tmp, entry)
        except OSError:
            if not net.is_file():  # not a concurrent build that won the race
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return net
