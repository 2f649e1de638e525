"""The association node's parameters: one table with descriptions, units and ranges.

The defaults of the physical bounds are those of :class:`mlkm_core.bounds.Bounds`;
config/association_node.param.yaml repeats every default (a test keeps them equal).
"""

from __future__ import annotations

from mlkm_core.associators.base import available_methods
from mlkm_core.bounds import Bounds
from mlkm_ros.params import ParamSpec, positive

#: Parameters of stream mode (mlkm_assoc.modes), read once at start-up.
STREAM_PARAMS = ('mode', 'lag', 'stream_method')
#: Parameters of the node itself, not of the assembly.
NODE_PARAMS = (
    'diagnostics_period',
    'diagnostics_window',
    'warn_rejected_fraction',
    'max_uncommitted',
    *STREAM_PARAMS,
)
_BOUNDS = Bounds()
BOUND_NAMES = ('min_speed', 'max_speed', 'min_stamp', 'max_stamp', 'min_length', 'max_length')


def _check_method(value: str) -> str | None:
    methods = available_methods()
    if value in methods:
        return None
    return f'unknown method {value!r}; choose one of {", ".join(methods)}'


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
    ParamSpec(
        'method',
        'mlkm',
        'associator from the core, any of mlkm_core available_methods() (applies from '
        'the next episode); also of stream mode when given without stream_method [-]',
        check=_check_method,
        constraints='one of: ' + ', '.join(available_methods()),
    ),
    ParamSpec(
        'segment_size',
        5,
        'K: sensors per road segment; one association update per completed segment '
        '(applies from the next episode) [-]',
        1,
        100000,
    ),
    ParamSpec(
        'seed',
        0,
        'random state of the associator (applies from the next episode) [-]',
        0,
        2**31 - 1,
    ),
    ParamSpec(
        'completion_timeout',
        5.0,
        'after an episode ended, associate what is there once nothing arrived for this '
        'long; also how long a detection waits for its episode [s]',
        1e-3,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'episode_timeout',
        60.0,
        'an episode that never ended (its source died) is finalised with what it has once '
        'nothing arrived for it this long [s]',
        1e-3,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'max_finished_episodes',
        100,
        'finished episodes remembered to recognise their late detections; older ones are '
        'forgotten [-]',
        1,
        1_000_000,
    ),
    ParamSpec(
        'min_speed',
        _BOUNDS.min_speed,
        'slowest plausible detection velocity; slower ones are rejected [m/s]',
        1e-9,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'max_speed',
        _BOUNDS.max_speed,
        'fastest plausible detection velocity; faster ones are rejected [m/s]',
        1e-9,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'min_stamp',
        _BOUNDS.min_stamp,
        'earliest plausible detection stamp; earlier ones are rejected [s]',
        0.0,
        float(2**31 - 1),
    ),
    ParamSpec(
        'max_stamp',
        _BOUNDS.max_stamp,
        'latest plausible detection stamp; later ones are rejected [s]',
        0.0,
        float(2**31 - 1),
    ),
    ParamSpec(
        'min_length',
        _BOUNDS.min_length,
        'shortest plausible measured vehicle length; shorter ones are rejected (a length of '
        'NaN or 0 means not measured and is accepted) [m]',
        1e-9,
        1e6,
        check=positive,
    ),
    ParamSpec(
        'max_length',
        _BOUNDS.max_length,
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
        15.0,
        'stream mode: a link may be revised until the newest stamp is this far past the '
        "detection's stamp, then it is committed; a road without detections for this long "
        '(wall time) is flushed [s]',
        1e-3,
        1e6,
        check=positive,
        read_only=True,
    ),
    ParamSpec(
        'stream_method',
        'multiframe',
        "stream mode: associator of the tracker's window solves, any of mlkm_core "
        'available_methods(); when not given, the method given, else this default [-]',
        check=_check_method,
        constraints='one of: ' + ', '.join(available_methods()),
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
]
