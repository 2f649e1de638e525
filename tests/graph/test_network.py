"""DDS stays on loopback (ss checks the sockets; no shared memory), and what env.sh gives.

The loopback default: env.sh, the launchers (graph_env) and the test fixtures select the Fast
DDS profile mlkm_ros/fastdds_loopback.xml unless the user chose otherwise.
"""

from __future__ import annotations

import ipaddress
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from mlkm_ros.domains import graph_env
from mlkm_ros.network import LOOPBACK_PROFILE, loopback_env

REPO = Path(__file__).resolve().parents[2]
ENV_SH = REPO / 'env.sh'


def _udp_sockets(pid: int) -> list[str]:
    """Local addresses of the UDP sockets of process ``pid`` (``ss -uanp``)."""
    out = subprocess.run(['ss', '-uanp'], capture_output=True, text=True, check=True).stdout
    return [line.split()[3] for line in out.splitlines() if f'pid={pid},' in line]


def _host(address: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address:
    host = address.rsplit(':', 1)[0].strip('[]').split('%')[0]
    return ipaddress.ip_address(host)


@pytest.mark.ros
@pytest.mark.skipif(shutil.which('ss') is None, reason='needs ss (iproute2)')
def test_a_running_node_binds_udp_on_loopback_only(ros_process) -> None:
    sim = ros_process(
        'road_sensors',
        'sensor_sim',
        '--ros-args',
        '-p', 'n_sensors:=3',
        '-p', 'n_targets:=2',
        '-p', 'wait_for_subscribers:=1',
        '-p', 'wait_timeout:=0.0',
    )  # fmt: skip
    assert sim.wait_for_output('waiting for 1 subscriber(s)', timeout=120), sim.output()
    sockets = _udp_sockets(sim.pid)
    assert sockets, 'the node has no UDP socket at all: is the profile a valid one?'
    outside = [a for a in sockets if not _host(a).is_loopback]
    assert outside == [], f'sockets beyond loopback: {outside} (all: {sockets})'
    # no shared-memory transport: a peer killed with SIGKILL could leave its ports unusable
    maps = Path(f'/proc/{sim.pid}/maps').read_text()
    shm = sorted({line.split()[-1] for line in maps.splitlines() if '/dev/shm/fastrtps' in line})
    assert shm == [], f'Fast DDS shared memory mapped: {shm}'


def test_the_profile_is_the_default_of_launchers_and_fixtures(ros_env) -> None:
    for env in (ros_env, graph_env(42)):
        if env.get('MLKM_DDS_LOOPBACK') == '0':
            pytest.skip('MLKM_DDS_LOOPBACK=0 in this shell')
        assert env['FASTRTPS_DEFAULT_PROFILES_FILE'] == str(LOOPBACK_PROFILE)
        assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SYSTEM_DEFAULT'
    assert LOOPBACK_PROFILE.is_file()


@pytest.mark.parametrize(
    ('given', 'profile', 'scope'),
    [
        ({}, str(LOOPBACK_PROFILE), 'SYSTEM_DEFAULT'),
        ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}, str(LOOPBACK_PROFILE), 'SYSTEM_DEFAULT'),
        ({'MLKM_DDS_LOOPBACK': '0'}, None, 'LOCALHOST'),
        ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}, None, 'SUBNET'),
        ({'ROS_STATIC_PEERS': '10.0.0.2'}, None, 'LOCALHOST'),
        ({'FASTRTPS_DEFAULT_PROFILES_FILE': '/etc/mine.xml'}, '/etc/mine.xml', 'LOCALHOST'),
        ({'FASTDDS_DEFAULT_PROFILES_FILE': '/etc/mine.xml'}, None, 'LOCALHOST'),
        # applied twice: unchanged; turned off after being applied: undone
        (
            {
                'FASTRTPS_DEFAULT_PROFILES_FILE': str(LOOPBACK_PROFILE),
                'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SYSTEM_DEFAULT',
            },
            str(LOOPBACK_PROFILE),
            'SYSTEM_DEFAULT',
        ),
        (
            {
                'FASTRTPS_DEFAULT_PROFILES_FILE': str(LOOPBACK_PROFILE),
                'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SYSTEM_DEFAULT',
                'MLKM_DDS_LOOPBACK': '0',
            },
            None,
            'LOCALHOST',
        ),
    ],
)
def test_loopback_env_respects_the_users_choice(given, profile, scope) -> None:
    env = loopback_env(dict(given))
    assert env.get('FASTRTPS_DEFAULT_PROFILES_FILE') == profile
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == scope


def _bash(script: str, **extra: str) -> str:
    """Run ``script`` in a fresh bash (a clean environment plus ``extra``), return stdout."""
    env = {'HOME': os.environ.get('HOME', '/tmp'), 'PATH': '/usr/bin:/bin', **extra}
    done = subprocess.run(
        ['bash', '--noprofile', '--norc', '-c', script],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_env_sh_selects_the_profile_and_mlkm_dds_loopback_0_turns_it_off() -> None:
    show = 'echo "${FASTRTPS_DEFAULT_PROFILES_FILE:-none} $ROS_AUTOMATIC_DISCOVERY_RANGE"'
    on = _bash(f'source {ENV_SH} >/dev/null; {show}; source {ENV_SH} >/dev/null; {show}')
    assert on.split('\n')[:2] == [f'{LOOPBACK_PROFILE} SYSTEM_DEFAULT'] * 2
    off = _bash(f'source {ENV_SH} >/dev/null; {show}', MLKM_DDS_LOOPBACK='0')
    assert off.strip() == 'none LOCALHOST'
    later = _bash(
        f'source {ENV_SH} >/dev/null; MLKM_DDS_LOOPBACK=0; source {ENV_SH} >/dev/null; {show}'
    )
    assert later.strip() == 'none LOCALHOST'
    subnet = _bash(f'source {ENV_SH} >/dev/null; {show}', ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET')
    assert subnet.strip() == 'none SUBNET'


@pytest.fixture
def fake_ros2(tmp_path: Path) -> Path:
    """A directory with a `ros2` executable that says who it is."""
    bindir = tmp_path / 'bin'
    bindir.mkdir()
    exe = bindir / 'ros2'
    exe.write_text('#!/bin/sh\necho "real ros2: $*"\n')
    exe.chmod(0o755)
    return bindir


def test_env_sh_never_hides_a_real_ros2(fake_ros2: Path) -> None:
    # On PATH before sourcing (twice): no shim.
    out = _bash(
        f'PATH={fake_ros2}:$PATH; source {ENV_SH} >/dev/null; source {ENV_SH} >/dev/null; '
        'type -t ros2; ros2 topic list'
    )
    assert out.split('\n')[:2] == ['file', 'real ros2: topic list']
    # Put on PATH after sourcing: the shim hands over.
    out = _bash(f'source {ENV_SH} >/dev/null; PATH={fake_ros2}:$PATH; ros2 topic list')
    assert out.strip() == 'real ros2: topic list'
    # Sourced again in between (the venv's activate restores its own PATH): still the real one.
    out = _bash(
        f'source {ENV_SH} >/dev/null; PATH={fake_ros2}:$PATH; source {ENV_SH} >/dev/null; '
        f'PATH={fake_ros2}:$PATH; ros2 topic list'
    )
    assert out.strip() == 'real ros2: topic list'


def test_env_sh_shim_runs_an_installed_executable_without_ros2cli() -> None:
    out = _bash(
        f'source {ENV_SH} >/dev/null; type -t ros2; ros2 nope 2>&1; echo "exit $?"; '
        'ros2 run road_sensors no_such_exe 2>&1; echo "exit $?"'
    )
    lines = out.strip().split('\n')
    assert lines[0] == 'function'
    assert 'env.sh only provides' in lines[1] and lines[2] == 'exit 2'
    assert "no executable 'no_such_exe' in package 'road_sensors'" in lines[3]
    assert lines[4] == 'exit 1'
