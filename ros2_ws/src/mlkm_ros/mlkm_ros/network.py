"""The embedded network default: DDS on the loopback interface only.

``loopback_env(env)`` is what env.sh does in bash, for the environments of the processes the
launchers and the tests start. Unless the user chose otherwise it selects the Fast DDS profile
``fastdds_loopback.xml`` (every socket on 127.0.0.1, unicast discovery to 127.0.0.1, no
multicast, no shared memory: a killed process can leave its peers' shared-memory ports
unusable) with ``ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT``: with the LOCALHOST range,
rmw_fastrtps adds a UDP transport of its own that binds 0.0.0.0 and every interface's address,
so only the profile keeps the sockets on loopback. Discovery stays local.

The user chose otherwise when any of these is set: ``MLKM_DDS_LOOPBACK=0``, a Fast DDS profile
file of their own (``FASTRTPS_DEFAULT_PROFILES_FILE`` / ``FASTDDS_DEFAULT_PROFILES_FILE``),
``ROS_STATIC_PEERS``, or a discovery range other than LOCALHOST. Then only the range defaults
to LOCALHOST, as before.
"""

from __future__ import annotations

from collections.abc import MutableMapping
from pathlib import Path

#: The profile (installed next to this module).
LOOPBACK_PROFILE = Path(__file__).resolve().with_name('fastdds_loopback.xml')
#: Read by Fast DDS 2.x (Jazzy) for the default profile file.
PROFILE_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'
#: Read by Fast DDS 3.x; a user setting it has a profile of their own.
OTHER_PROFILE_VARIABLE = 'FASTDDS_DEFAULT_PROFILES_FILE'
RANGE_VARIABLE = 'ROS_AUTOMATIC_DISCOVERY_RANGE'
SWITCH_VARIABLE = 'MLKM_DDS_LOOPBACK'


def loopback_env(env: MutableMapping[str, str]) -> MutableMapping[str, str]:
    """Apply the loopback-only default to ``env`` (in place, e.g. a copy of os.environ)."""
    ours = str(LOOPBACK_PROFILE)
    profile = env.get(PROFILE_VARIABLE, '')
    scope = env.get(RANGE_VARIABLE, '')
    applied_before = profile == ours  # a parent process (or env.sh) applied it already
    wanted = (
        env.get(SWITCH_VARIABLE, '1') != '0'
        and not env.get('ROS_STATIC_PEERS')
        and profile in ('', ours)
        and not env.get(OTHER_PROFILE_VARIABLE)
        and (scope in ('', 'LOCALHOST') or (applied_before and scope == 'SYSTEM_DEFAULT'))
        and LOOPBACK_PROFILE.is_file()
    )
    if wanted:
        env[PROFILE_VARIABLE] = ours
        env[RANGE_VARIABLE] = 'SYSTEM_DEFAULT'
        return env
    if applied_before:  # turned off since: undo what the default set
        del env[PROFILE_VARIABLE]
        if scope == 'SYSTEM_DEFAULT':
            env.pop(RANGE_VARIABLE)
    env.setdefault(RANGE_VARIABLE, 'LOCALHOST')
    return env


def loopback_active(env: MutableMapping[str, str]) -> bool:
    """Whether ``env`` selects the loopback-only profile."""
    return env.get(PROFILE_VARIABLE) == str(LOOPBACK_PROFILE)
