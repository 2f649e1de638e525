"""Drawing the time-space diagram (``mlkm plot``) to PNG, and reading a tracks CSV for it.

The figure's content comes from :func:`mlkm_core.timespace.time_space`; this module only
reads the input and draws: every link of one colour per track (one ``LineCollection``, so
that 100k detections draw in about a second), the wrong links in red on top, the unassigned
detections as grey crosses and the stations as thin horizontal lines. matplotlib is imported
when a figure is drawn, never at import, and only through its Agg canvas (no GUI, no pyplot
state).
"""

from __future__ import annotations

import io
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mlkm_core.csvio import read_detections
from mlkm_core.timespace import TimeSpace, time_space

#: Name of the diagram written beside a bag directory ``<bag>``: ``<bag>_timespace.png``.
BESIDE_SUFFIX = '_timespace.png'
#: Stamps above this [s] are times since the Unix epoch (ROS time): the x axis then counts
#: from the first detection, named in the axis label.
EPOCH_STAMPS = 1e6
#: Figure size [inch] and resolution [dpi] of the PNG.
FIGSIZE = (11.0, 6.0)
DPI = 110
#: Detections drawn as dots up to this many; beyond, only the lines.
MAX_DOTS = 20_000
WRONG_COLOUR = '#d62728'
CROSS_COLOUR = '#555555'


@dataclass
class PlotInput:
    """Detections to draw: one entry per detection in each array."""

    position: np.ndarray  # [m]
    stamp: np.ndarray  # [s]
    labels: np.ndarray  # track label, -1 = unassigned
    target: np.ndarray | None  # true target, -1 = false alarm; None without ground truth
    stations: np.ndarray  # station positions [m]
    source: str  # what the detections were read from, for the title
    notes: list[str] = field(default_factory=list)  # what was left out, for a warning


def read_tracks_csv(path: str | Path, network=None, route: str | None = None) -> PlotInput:
    """A tracks CSV as ``mlkm associate --output`` writes it (the detections CSV plus
    ``track_id``). Rows the reader refuses (a file written with ``--skip-invalid`` keeps them,
    with track -1) are left out and counted in ``notes``. With ``network`` (a RoadNetwork:
    the file's rows are its stations) the detections on one route (:func:`on_route`).
    Raises InputError, or ValueError for a bad route."""
    data = read_detections(path, skip_invalid=True, tracks=True, network=network)
    dets = data.detections
    notes = [f'{len(data.problems)} invalid row(s) left out'] if data.problems else []
    if network is not None:
        return on_route(
            network, route, dets.sensor_index, dets.stamp, data.track, dets.target, str(path),
            notes,
        )  # fmt: skip
    return PlotInput(
        position=data.layout.positions[dets.sensor_index],
        stamp=dets.stamp,
        labels=data.track,
        target=dets.target,
        stations=data.layout.positions,
        source=str(path),
        notes=notes,
    )


def on_route(
    net, route: str | None, station, stamp, labels, target, source: str, notes: list[str]
) -> PlotInput:
    """The detections of a road network (``station``: indexes of ``net``'s stations) on one
    route (``mlkm_core.network_route``: ``route`` names its links, comma-separated; None: the
    route with the most stations), at their distance along it. The route's name goes into
    ``source`` for the title; the detections elsewhere are counted in ``notes``."""
    from mlkm_core.network_route import main_route, parse_route, route_stations

    links = parse_route(net, route) if route else main_route(net)
    along = route_stations(net, links)
    if not along:
        raise ValueError('route: no station stands on it')
    station = np.asarray(station, np.int64)
    keep = np.isin(station, list(along))
    distance = np.array([along.get(int(s), np.nan) for s in station[keep]])
    names = {k.link_id: k.name for k in net.links}
    left = int(np.count_nonzero(~keep))
    notes = notes + ([f'{left} detection(s) off the route left out'] if left else [])
    return PlotInput(
        position=distance,
        stamp=np.asarray(stamp, float)[keep],
        labels=np.asarray(labels, np.int64)[keep],
        target=None if target is None else np.asarray(target, np.int64)[keep],
        stations=np.array(sorted(along.values())),
        source=f'{source} (route {" > ".join(names[k] for k in links)})',
        notes=notes,
    )


def summary(ts: TimeSpace, n: int) -> str:
    """One line: what the figure shows."""
    line = (
        f'{n} detections, {ts.tracks.size} tracks, {len(ts.crosses)} unassigned, '
        f'{len(ts.links)} links'
    )
    if ts.has_truth:
        line += f', {ts.n_wrong} wrong'
    return line


def draw(ts: TimeSpace, path: str | Path, title: str, stations: np.ndarray) -> None:
    """Write the diagram of ``ts`` as a PNG to ``path`` (written whole or not at all)."""
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    stamps = [ts.points[:, 0], ts.crosses[:, 0]]
    t_min = min((float(s.min()) for s in stamps if s.size), default=0.0)
    origin = t_min if t_min > EPOCH_STAMPS else 0.0
    xlabel = 'stamp [s]'
    if origin:
        utc = time.strftime('%Y-%m-%d %H:%M:%S', time.gmtime(origin))
        xlabel = f'time since the first detection, {utc} UTC [s]'

    fig = Figure(figsize=FIGSIZE, dpi=DPI)
    ax = fig.add_subplot()
    for y in np.asarray(stations, float):
        ax.axhline(y, color='#dddddd', linewidth=0.6, zorder=0)
    n_links = len(ts.links)
    width = 1.2 if n_links < 2_000 else 0.7 if n_links < 20_000 else 0.4
    palette = _palette()
    colour_of = np.searchsorted(ts.tracks, ts.link_track) % len(palette)
    shifted = ts.links - np.array([origin, 0.0])
    lines, first = _polylines(shifted, ts.link_track, ~ts.wrong)
    ax.add_collection(
        LineCollection(lines, colors=palette[colour_of[first]], linewidths=width, zorder=2)
    )
    if ts.n_wrong:
        ax.add_collection(
            LineCollection(
                shifted[ts.wrong], colors=WRONG_COLOUR, linewidths=1.5 * width + 0.2, zorder=3
            )
        )
    size = 9 if len(ts.points) < 5_000 else 2
    if len(ts.points) <= MAX_DOTS:  # beyond, the lines show where the detections are
        point_colour = palette[np.searchsorted(ts.tracks, ts.point_track) % len(palette)]
        ax.scatter(
            ts.points[:, 0] - origin, ts.points[:, 1], s=size, c=point_colour, lw=0, zorder=2
        )
    ax.scatter(
        ts.crosses[:, 0] - origin,
        ts.crosses[:, 1],
        s=4 * size,
        marker='x',
        c=CROSS_COLOUR,
        linewidths=0.8,
        zorder=4,
    )
    ax.autoscale_view()
    ax.set_xlabel(xlabel)
    ax.set_ylabel('position along the road [m]')
    ax.set_title(title, fontsize=10)
    legend = [
        Line2D([], [], color=palette[0], lw=1.5, label='track (one colour per track id)'),
        Line2D([], [], color=CROSS_COLOUR, marker='x', lw=0, label='unassigned detection'),
    ]
    if ts.has_truth:
        legend.append(
            Line2D([], [], color=WRONG_COLOUR, lw=2.5, label='wrong link (two true targets)')
        )
    ax.legend(handles=legend, loc='upper left', bbox_to_anchor=(1.005, 1.0), fontsize=8)
    ax.margins(x=0.01, y=0.03)
    fig.tight_layout()
    _save_png(fig, Path(path))


def _save_png(fig, path: Path) -> None:
    """Write ``fig`` as a PNG of 256 colours (a third of the full-colour size, the lines
    look the same), through a temporary file: whole or not at all."""
    from PIL import Image

    buffer = io.BytesIO()
    fig.savefig(buffer, format='png')
    buffer.seek(0)
    with Image.open(buffer) as image:
        small = image.convert('RGB').quantize(colors=256)
    tmp = path.with_name(f'.{path.name}.tmp')
    try:
        small.save(tmp, format='PNG')
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


def _polylines(
    links: np.ndarray, track: np.ndarray, keep: np.ndarray
) -> tuple[list[np.ndarray], np.ndarray]:
    """The kept links joined into polylines: runs of consecutive links of one track (the
    order of :class:`~mlkm_core.timespace.TimeSpace`), so that a collection holds one path
    per track piece instead of one per link. Returns them and the first link of each."""
    idx = np.flatnonzero(keep)
    if not idx.size:
        return [], idx
    cut = np.flatnonzero((np.diff(idx) != 1) | (track[idx[1:]] != track[idx[:-1]])) + 1
    runs = np.split(idx, cut)
    lines = [np.concatenate([links[r, 0], links[r[-1], 1][None]]) for r in runs]
    return lines, idx[np.concatenate([[0], cut])]


def _palette() -> np.ndarray:
    """RGB colours of the tracks: tab20's dark shades, then its light ones, so that tracks of
    neighbouring ids differ in hue; without its reds (red marks the wrong links)."""
    from matplotlib import colormaps

    colours = colormaps['tab20'].colors
    order = [*range(0, 20, 2), *range(1, 20, 2)]
    return np.array([colours[i] for i in order if i not in (6, 7)])


def plot(data: PlotInput, output: str | Path, title: str | None = None) -> str:
    """Draw ``data`` to ``output``; returns the summary line. The default title is the
    input's name and the summary; ``{summary}`` in ``title`` is replaced by the summary."""
    ts = time_space(data.position, data.stamp, data.labels, data.target)
    line = summary(ts, len(data.stamp))
    title = (title or f'{Path(data.source).name}: {{summary}}').replace('{summary}', line)
    draw(ts, output, title, data.stations)
    return line


def beside(bag: str | Path, replay: bool = False) -> Path:
    """Where the diagram of the bag ``bag`` goes: ``<bag>_timespace.png`` beside it (the bag
    directory's name, or the .mcap file's without its suffix); ``<bag>_replay_timespace.png``
    for the tracks of a replay."""
    bag = Path(bag)
    name = bag.stem if bag.suffix == '.mcap' else bag.name
    return bag.with_name(name + ('_replay' if replay else '') + BESIDE_SUFFIX)


def plot_beside_bag(bag: str | Path, tracks: list | None = None) -> str:
    """Draw the diagram of a recorded bag beside it (:func:`beside`); with ``tracks``
    (TrackArray messages of a replay) those tracks, with the bag's layout and truth. Returns
    the line a demo prints: the path, or why there is no diagram (a demo's run does not fail
    by its figure)."""
    from mlkm_assoc.timespace_bag import read_bag

    output = beside(bag, replay=tracks is not None)
    try:
        data = read_bag(bag, tracks)
        title = None if tracks is None else f'replay of {Path(bag).name}: {{summary}}'
        line = plot(data, output, title)
    except Exception as exc:  # noqa: BLE001 - the figure never fails the run it illustrates
        why = str(exc) if isinstance(exc, (OSError, ValueError)) else repr(exc)
        return f'time-space diagram: not written: {why}'
    return f'time-space diagram: {output}  ({line})'
