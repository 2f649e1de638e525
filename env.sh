# shellcheck shell=bash
# Source me in a new terminal (bash), from any directory:   source /path/to/repo/env.sh
#
# It gives: the ROS 2 Jazzy underlay (the wheels in .venv, or /opt/ros/jazzy when `make setup`
# chose it), the project venv, the ros2_ws/install overlay (road_sensor_msgs and the packages),
# ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless already set, every package executable on PATH
# (mlkm, sensor_sim, ...) and, when the real ros2cli is absent, a `ros2 run <pkg> <exe> [args]`
# shell function. Safe under `set -u` and `set -e`, and to source twice.
# MLKM_ENV_NO_OVERLAY=1 skips the overlay (scripts/setup.sh uses that while rebuilding it).

_mlkm_src=${BASH_SOURCE[0]:-$0}
MLKM_ROOT=$(cd "$(dirname "$_mlkm_src")" && pwd)
export MLKM_ROOT
unset _mlkm_src

if [[ ! -x $MLKM_ROOT/.venv/bin/python ]]; then
  echo "env.sh: $MLKM_ROOT/.venv is missing; run 'make setup' in $MLKM_ROOT first" >&2
  return 1 2>/dev/null || exit 1
fi

# ROS setup scripts and venv activation are not written for `set -u`.
_mlkm_had_u=0
[[ $- == *u* ]] && _mlkm_had_u=1
set +u

# Prepend $2 to the colon-separated variable named $1, once.
_mlkm_prepend() {
  local cur=${!1:-}
  case ":$cur:" in
    *":$2:"*) ;;
    *) export "$1=$2${cur:+:$cur}" ;;
  esac
}

# --- underlay -------------------------------------------------------------------------------
_mlkm_underlay=
[[ -f $MLKM_ROOT/.venv/mlkm-underlay ]] && _mlkm_underlay=$(<"$MLKM_ROOT/.venv/mlkm-underlay")
if [[ -n $_mlkm_underlay ]]; then
  # shellcheck disable=SC1090,SC1091
  source "$_mlkm_underlay/setup.bash"
fi

# shellcheck disable=SC1091
source "$MLKM_ROOT/.venv/bin/activate"

if [[ -z $_mlkm_underlay ]]; then
  # The venv is the ROS prefix (like /opt/ros/jazzy): ament index, CMake configs, libraries.
  _mlkm_venv=$MLKM_ROOT/.venv
  _mlkm_prepend AMENT_PREFIX_PATH "$_mlkm_venv"
  _mlkm_prepend CMAKE_PREFIX_PATH "$_mlkm_venv"
  # What the wheels' ros_wheels_bootstrapper would set by re-executing every Python start:
  # lib/ and the site-packages/ros_*.libs directories. Setting it here (and the bootstrapper's
  # guard) saves that re-exec and lets non-Python processes load the ROS libraries.
  for _mlkm_d in "$_mlkm_venv"/lib/python3.*/site-packages/ros_*.libs; do
    [[ -d $_mlkm_d ]] && _mlkm_prepend LD_LIBRARY_PATH "$_mlkm_d"
  done
  _mlkm_prepend LD_LIBRARY_PATH "$_mlkm_venv/lib"
  export _ROS_WHEELS_BOOTSTRAP_COMPLETE=1
  export ROS_DISTRO=${ROS_DISTRO:-jazzy}
  export ROS_VERSION=${ROS_VERSION:-2}
  export ROS_PYTHON_VERSION=${ROS_PYTHON_VERSION:-3}
  unset _mlkm_venv _mlkm_d
fi

# --- overlay: ros2_ws/install -------------------------------------------------------------------
_mlkm_install=$MLKM_ROOT/ros2_ws/install
if [[ ${MLKM_ENV_NO_OVERLAY:-0} != 1 ]]; then
  if [[ -f $_mlkm_install/local_setup.bash ]]; then
    # shellcheck disable=SC1091
    source "$_mlkm_install/local_setup.bash"
    for _mlkm_d in "$_mlkm_install"/*/lib/*; do
      [[ -d $_mlkm_d && $(basename "$_mlkm_d") == $(basename "$(dirname "$(dirname "$_mlkm_d")")") ]] \
        && _mlkm_prepend PATH "$_mlkm_d"
    done
    unset _mlkm_d
  else
    echo "env.sh: $_mlkm_install is not built yet; run 'make setup'" >&2
  fi
fi

# --- network: loopback only unless the user says otherwise -----------------------------------------
# The Fast DDS profile binds every socket to 127.0.0.1 (no multicast; discovery by unicast to
# 127.0.0.1). It needs the SYSTEM_DEFAULT range: with LOCALHOST, rmw_fastrtps adds a UDP
# transport that binds every interface. The user's choice wins: MLKM_DDS_LOOPBACK=0, a profile
# file of their own, ROS_STATIC_PEERS or another range keep the plain LOCALHOST default.
# mlkm_ros/network.py (loopback_env) does the same for the processes the scripts start.
_mlkm_profile=$MLKM_ROOT/ros2_ws/src/mlkm_ros/mlkm_ros/fastdds_loopback.xml
_mlkm_range=${ROS_AUTOMATIC_DISCOVERY_RANGE:-}
_mlkm_ours=0
[[ ${FASTRTPS_DEFAULT_PROFILES_FILE:-} == "$_mlkm_profile" ]] && _mlkm_ours=1
if [[ ${MLKM_DDS_LOOPBACK:-1} != 0 && -z ${ROS_STATIC_PEERS:-} && -f $_mlkm_profile ]] \
  && [[ -z ${FASTRTPS_DEFAULT_PROFILES_FILE:-} || $_mlkm_ours == 1 ]] \
  && [[ -z ${FASTDDS_DEFAULT_PROFILES_FILE:-} ]] \
  && [[ -z $_mlkm_range || $_mlkm_range == LOCALHOST \
    || ($_mlkm_ours == 1 && $_mlkm_range == SYSTEM_DEFAULT) ]]; then
  export FASTRTPS_DEFAULT_PROFILES_FILE=$_mlkm_profile
  export ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT
else
  if [[ $_mlkm_ours == 1 ]]; then # turned off since an earlier `source env.sh`
    unset FASTRTPS_DEFAULT_PROFILES_FILE
    [[ $_mlkm_range == SYSTEM_DEFAULT ]] && unset ROS_AUTOMATIC_DISCOVERY_RANGE
  fi
  export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
fi
unset _mlkm_profile _mlkm_range _mlkm_ours

# --- `ros2 run` without ros2cli -------------------------------------------------------------------
# A real ros2 executable always wins: the shim is not defined when one is on PATH, an earlier
# shim is removed, and a shim defined before ros2cli came onto PATH hands over to it.
if type -P ros2 >/dev/null 2>&1; then
  if [[ $(type -t ros2) == function ]] && declare -f ros2 | grep -q _mlkm_ros2_shim; then
    unset -f ros2
  fi
else
  ros2() {
    : _mlkm_ros2_shim
    if type -P ros2 >/dev/null 2>&1; then
      command ros2 "$@"
      return
    fi
    if [[ ${1:-} != run || $# -lt 3 ]]; then
      echo "ros2: the ros2 command-line tools are not installed; env.sh only provides" \
        "'ros2 run <package> <executable> [args...]'" >&2
      return 2
    fi
    local pkg=$2 exe=$3
    shift 3
    local path=$MLKM_ROOT/ros2_ws/install/$pkg/lib/$pkg/$exe
    if [[ ! -d $MLKM_ROOT/ros2_ws/install/$pkg ]]; then
      echo "ros2 run: package '$pkg' not found in $MLKM_ROOT/ros2_ws/install" \
        "(run 'make setup')" >&2
      return 1
    fi
    if [[ ! -x $path ]]; then
      echo "ros2 run: no executable '$exe' in package '$pkg'; it has:" \
        "$(ls "$MLKM_ROOT/ros2_ws/install/$pkg/lib/$pkg" 2>/dev/null | tr '\n' ' ')" >&2
      return 1
    fi
    # A child process (not `exec`), so that the calling shell survives.
    "$path" "$@"
  }
fi

unset _mlkm_underlay _mlkm_install
unset -f _mlkm_prepend
((_mlkm_had_u)) && set -u
unset _mlkm_had_u
true
