"""The live processes of a process group (Linux /proc), for the tests that check that a run
leaves none behind. Not a test module: the graph tests import it by name."""

from __future__ import annotations

from pathlib import Path


def group(pgid: int) -> list[int]:
    """Pids of the processes of group ``pgid`` that are not zombies."""
    out = []
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[2]) == pgid and fields[0] != 'Z':
            out.append(int(stat.parent.name))
    return out
