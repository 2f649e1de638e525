# shellcheck shell=bash
# Tests only: after `source env.sh`, put the real ROS 2 command-line tools on this shell's paths
# (`ros2 launch`, `ros2 node/topic/param/interface ...`), as the tests that check the product
# against them do (tests/graph/ros2_tools.py):
#
#   source env.sh && source scripts/ros2_tools.sh
#
# With the PyPI wheels they are the upstream Jazzy sources of ../shared/vendor, which
# `make setup` installs into build/ros2_tools when that folder is there; with /opt/ros/jazzy they
# came with it and this does nothing. The product never needs them: env.sh does not source this.
# Returns 1, with the reason on stderr, when the tools are not available.

if [[ -z ${MLKM_ROOT:-} ]]; then
  echo 'ros2_tools.sh: source env.sh first' >&2
  return 1 2>/dev/null || exit 1
fi
_mlkm_tools=$MLKM_ROOT/build/ros2_tools
if [[ -f $_mlkm_tools/.mlkm-stamp ]]; then
  _mlkm_add() {  # prepend $2 to the colon-separated variable named $1, once
    local cur=${!1:-}
    case ":$cur:" in
      *":$2:"*) ;;
      *) export "$1=$2${cur:+:$cur}" ;;
    esac
  }
  # The Python packages (ros2cli, launch, launch_ros, ...): modules, entry points, `ros2`, and
  # their share/ament_index, where ros2cli finds its own packages.
  _mlkm_add PYTHONPATH "$_mlkm_tools/python"
  _mlkm_add PATH "$_mlkm_tools/python/bin"
  _mlkm_add AMENT_PREFIX_PATH "$_mlkm_tools/python"
  # composition_interfaces (a message package, colcon --merge-install).
  for _mlkm_d in "$_mlkm_tools"/install/lib/python3.*/site-packages; do
    [[ -d $_mlkm_d ]] && _mlkm_add PYTHONPATH "$_mlkm_d"
  done
  _mlkm_add LD_LIBRARY_PATH "$_mlkm_tools/install/lib"
  _mlkm_add AMENT_PREFIX_PATH "$_mlkm_tools/install"
  _mlkm_add CMAKE_PREFIX_PATH "$_mlkm_tools/install"
  unset -f _mlkm_add
  unset _mlkm_d
elif ! type -P ros2 >/dev/null 2>&1; then
  echo "ros2_tools.sh: the ros2 command-line tools are not installed: $_mlkm_tools was not" \
    'built (make setup builds it when ../shared/vendor exists)' >&2
  unset _mlkm_tools
  return 1 2>/dev/null || exit 1
fi
unset _mlkm_tools
# The real ros2 wins over env.sh's `ros2 run` shell function.
if [[ $(type -t ros2) == function ]] && declare -f ros2 | grep -q _mlkm_ros2_shim; then
  unset -f ros2
fi
true
