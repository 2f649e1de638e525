"""The association node's parameters: one table with descriptions, units and ranges.

The defaults of the assembly's settings are those of :class:`AssociationConfig` (whose
bounds are :class:`mlkm_core.bounds.Bounds`), those of stream mode the core's
:class:`~mlkm_core.streaming.config.StreamConfig`; config/association_node.param.yaml repeats
every default for users (a test keeps them equal).
"""

from __future__ import annotations

from mlkm_assoc.episodes import AssociationConfig
from mlkm_assoc.shard_link import SHARD_PARAMS, SHARD_SPECS
from mlkm_core.associators.base import available_methods
from mlkm_core.streaming.config import StreamConfig
from mlkm_ros.params import ParamSpec, positive

#: Parameters of stream mode (mlkm_assoc.modes), read once at start-up.
STREAM_PARAMS = ('mode', 'lag', 'stream_method')
#: Parameters of /mlkm/markers (mlkm_assoc.association_markers).
MARKER_PARAMS = ('markers', 'markers_rate', 'markers_parent_frame')
#: Parameters of the node itself, not of the assembly.
NODE_PARAMS = (
    *MARKER_PARAMS,
    'diagnostics_period',
    'diagnostics_window',
    'warn_rejected_fraction',
    'max_uncommitted',
    'quiet_flush',
    'wait_for_track_subscribers',
    'source_namespace',
    *STREAM_PARAMS,
    *SHARD_PARAMS,
)
_DEFAULTS = AssociationConfig()
_STREAM = StreamConfig()
BOUND_NAMES = ('min_speed', 'max_speed', 'min_stamp', 'max_stamp', 'min_length', 'max_length')


def _check_method(value: str) -> str | None:
    methods = available_methods()
    if value in methods:
        return None
    return f'unknown method {value!r}; choose one of {", ".join(methods)}'


def _method_spec(name: str, default: str, description: str, read_only: bool = False) -> ParamSpec:
    """A parameter naming one of the core's associators (the choices in its descriptor)."""
    return ParamSpec(
        name,
        default,
        description,
        read_only=read_only,
        check=_check_method,
        constraints='one of: ' + ', '.join(available_methods()),
    )


def stream_associator(method: str, stream_method: str, given: set[str]) -> str:
    """The associator of stream mode's window solves: ``stream_method`` when it was given
    (on the command line or in a params file), else ``method`` when that was given (so a
    method asked for is never ignored), else ``stream_method``'s default."""
    if 'stream_method' not in given and 'method' in given:
        return method
    return stream_method


def _check_mode(value: str) -> str | None:
    if value in ('auto', 'episodes', 'stream'):
        return None
    return f'unknown mode {value!r}; choose one of auto, episodes, stream'


SPECS = [
    _method_spec(
        'method',
        _DEFAULTS.method,
        'associator from the core, any of mlkm_core available_methods() (applies from '
        'the next episode); also of stream mode when given without stream_method [-]',
    ),
    ParamSpec(
        'segment_size',
        _DEFAULTS.segment_size,
        'K: sensors per road segment; one association update per completed segment '
        '(applies from the next episode) [-]',
        1,
        100000,
    ),
    ParamSpec(
        'seed',
        _DEFAULTS.seed,
        'random state of the associator (applies from the next episode) [-]',
        0,
        2**31 - 1,
    ),
    ParamSpec(
        'completion_timeout',
        _DEFAULTS.completion_timeout,
        'after an episode ended, associate what is there once nothing arrived for this '
        'long; also how long a detection waits for its episode [s]',
        1e-3,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'episode_timeout',
        _DEFAULTS.episode_timeout,
        'an episode that never ended (its source died) is finalised with what it has once '
        'nothing arrived for it this long [s]',
        1e-3,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'max_finished_episodes',
        _DEFAULTS.max_finished_episodes,
        'finished episodes remembered to recognise their late detections; older ones are '
        'forgotten [-]',
        1,
        1_000_000,
    ),
    ParamSpec(
        'min_speed',
        _DEFAULTS.min_speed,
        'slowest plausible detection velocity; slower ones are rejected [m/s]',
        1e-9,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'max_speed',
        _DEFAULTS.max_speed,
        'fastest plausible detection velocity; faster ones are rejected [m/s]',
        1e-9,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'min_stamp',
        _DEFAULTS.min_stamp,
        'earliest plausible detection stamp; earlier ones are rejected [s]',
        0.0,
        float(2**31 - 1),
    ),
    ParamSpec(
        'max_stamp',
        _DEFAULTS.max_stamp,
        'latest plausible detection stamp; later ones are rejected [s]',
        0.0,
        float(2**31 - 1),
    ),
    ParamSpec(
        'min_length',
        _DEFAULTS.min_length,
        'shortest plausible measured vehicle length; shorter ones are rejected (a length of '
        'NaN or 0 means not measured and is accepted) [m]',
        1e-9,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'max_length',
        _DEFAULTS.max_length,
        'longest plausible measured vehicle length; longer ones are rejected [m]',
        1e-9,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'mode',
        'auto',
        "episodes: the paper's closed world (EpisodeInfo windows and target counts); "
        'stream: an open road, every detection tracked at once; auto: episodes while '
        '/road/episode has a publisher, stream otherwise [-]',
        check=_check_mode,
        constraints='one of: auto, episodes, stream',
        read_only=True,
    ),
    ParamSpec(
        'lag',
        _STREAM.lag,
        'stream mode: a link may be revised until the newest stamp is this far past the '
        "detection's stamp, then it is committed; a road without detections for this long "
        '(wall time) is flushed, unless quiet_flush says otherwise [s]',
        1e-3,
        1e6,
        check=positive,
        read_only=True,
    ),
    ParamSpec(
        'quiet_flush',
        0.0,
        'stream mode: a road without detections for this long (wall time) is flushed: every '
        'link committed, every track FINAL; shorter than the lag for a log replayed faster '
        'than real time, where a quiet second of wall time is many seconds of stamps; 0 = '
        'the lag [s]',
        0.0,
        1e6,
        read_only=True,
    ),
    _method_spec(
        'stream_method',
        _STREAM.method,
        "stream mode: associator of the tracker's window solves, any of mlkm_core "
        'available_methods(); when not given, the method given, else this default [-]',
        read_only=True,
    ),
    ParamSpec(
        'max_uncommitted',
        100_000,
        'stream mode: most detections waiting for their commit; beyond, when the window '
        'solves cannot keep up, the due links are committed as first made, without a solve, '
        'until the backlog is taken (a bound on memory; WARN on /diagnostics); 0 = no bound '
        '[detections]',
        0,
        100_000_000,
        read_only=True,
    ),
    ParamSpec(
        'wait_for_track_subscribers',
        0,
        'hold the tracks until /mlkm/tracks has this many subscribers, then publish them in '
        'order (a scorer, recorder or tracker started with the graph misses none while DDS '
        'discovery completes); 0 = publish at once [-]',
        0,
        1000,
        read_only=True,
    ),
    ParamSpec(
        'markers',
        True,
        'publish /mlkm/markers: the road, its stations and their latest detections, each '
        'track placed along the road (visualization_msgs/MarkerArray, frame road) [-]',
    ),
    ParamSpec(
        'markers_rate',
        2.0,
        'most /mlkm/markers arrays per second (one only when something changed) [Hz]',
        0.01,
        100.0,
        check=positive,
        read_only=True,
    ),
    ParamSpec(
        'markers_parent_frame',
        'map',
        'parent frame of the road frame in the identity transform on /tf_static (published '
        'only where tf2_msgs is installed); empty: no transform [-]',
        read_only=True,
    ),
    ParamSpec(
        'diagnostics_period', 1.0, 'period of /diagnostics [s]', 0.01, 3600.0, read_only=True
    ),
    ParamSpec(
        'diagnostics_window',
        10.0,
        'the diagnostics level judges the inputs of this recent period [s]',
        0.01,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'warn_rejected_fraction',
        0.01,
        'WARN when more than this fraction of the detections received within '
        'diagnostics_window was rejected [-]',
        0.0,
        1.0,
    ),
    *SHARD_SPECS,
]
