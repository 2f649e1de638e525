#!/usr/bin/env bash
# `make setup`: the project's one-command, idempotent environment setup.
#
#   1. find CPython 3.12 and create .venv (if missing);
#   2. pip install requirements.txt (skipped when .venv's stamp matches its hash);
#   3. repair the ROS wheels' exported CMake include paths (scripts/fix_cmake_paths.py);
#   4. tests only: the upstream ros2cli and launch tools from ../shared/vendor into
#      build/ros2_tools (skipped when that folder is absent, when ROS comes from an existing
#      install that has them, or when the tarballs did not change); see scripts/ros2_tools.sh;
#   5. colcon build ros2_ws (skipped when nothing under ros2_ws/src changed).
#
# Two ways to get ROS 2 Jazzy:
#   - default: the PyPI wheels, installed into .venv, which is then the ROS underlay;
#   - an existing install: if /opt/ros/jazzy/setup.bash exists, or MLKM_ROS_UNDERLAY=<prefix>
#     is set, that underlay is sourced, .venv is made with --system-site-packages from the
#     system's Python 3.12, and only the non-ROS dependencies are installed (colcon must come
#     with the ROS install: python3-colcon-common-extensions).
#     MLKM_ROS_UNDERLAY=wheels forces the wheels even when /opt/ros/jazzy exists.
# The choice is recorded in .venv/mlkm-underlay; env.sh reads it. Switching needs `rm -rf .venv`.
#
# Other knobs: MLKM_PYTHON=/path/to/python3.12 (interpreter to use), MLKM_SETUP_FORCE=1 (ignore
# the stamps and redo every step).
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
VENV=$ROOT/.venv
REQ=$ROOT/requirements.txt
WS=$ROOT/ros2_ws
FORCE=${MLKM_SETUP_FORCE:-0}

log() { printf 'setup: %s\n' "$*"; }
die() { printf 'setup: ERROR: %s\n' "$*" >&2; exit 1; }
hash_of() { sha256sum | cut -c1-64; }

# One setup at a time per checkout (several terminals may run make targets at once).
mkdir -p "$WS/log"
exec 9>"$WS/log/.mlkm-setup.lock"
if ! flock -n 9; then
  log 'waiting for another make setup in this checkout to finish'
  flock 9
fi

# --- 0. which ROS 2 ---------------------------------------------------------------------------
UNDERLAY=${MLKM_ROS_UNDERLAY:-}
if [[ $UNDERLAY == wheels ]]; then
  UNDERLAY=
elif [[ -z $UNDERLAY && -f /opt/ros/jazzy/setup.bash ]]; then
  UNDERLAY=/opt/ros/jazzy
fi
if [[ -n $UNDERLAY && ! -f $UNDERLAY/setup.bash ]]; then
  die "MLKM_ROS_UNDERLAY=$UNDERLAY has no setup.bash"
fi
MODE=${UNDERLAY:-wheels}

# --- 1. Python 3.12 and the venv ---------------------------------------------------------------
is_py312() {
  [[ -n $1 && -x $1 ]] && "$1" -c \
    'import sys; sys.exit(not (sys.implementation.name == "cpython" and sys.version_info[:2] == (3, 12)))' \
    >/dev/null 2>&1
}

find_python() {
  local c candidates=()
  [[ -n ${MLKM_PYTHON:-} ]] && candidates+=("$MLKM_PYTHON")
  if [[ -n $UNDERLAY ]]; then
    # ROS 2 Jazzy's binaries are built for the system Python (Ubuntu 24.04: 3.12).
    candidates+=(/usr/bin/python3.12 /usr/bin/python3)
  fi
  c=$(type -P python3.12 || true) && [[ -n $c ]] && candidates+=("$c")
  if command -v pyenv >/dev/null 2>&1; then
    c=$(pyenv prefix 3.12.1 2>/dev/null || true)
    [[ -n $c ]] && candidates+=("$c/bin/python3.12")
    local root
    root=$(pyenv root 2>/dev/null || true)
    if [[ -n $root ]]; then
      for c in "$root"/versions/3.12*/bin/python3.12; do candidates+=("$c"); done
    fi
  fi
  c=$(type -P python3 || true) && [[ -n $c ]] && candidates+=("$c")
  for c in "${candidates[@]}"; do
    # A pyenv shim is on PATH even when it cannot run 3.12; is_py312 actually runs it.
    if is_py312 "$c"; then
      "$c" -c 'import sys; print(sys.executable)'
      return 0
    fi
  done
  return 1
}

venv_ok() {
  is_py312 "$VENV/bin/python" && [[ -f $VENV/mlkm-underlay ]]
}

if venv_ok; then
  recorded=$(<"$VENV/mlkm-underlay")
  if [[ ${recorded:-wheels} != "$MODE" ]]; then
    die ".venv was made for ROS underlay '${recorded:-wheels}', now '$MODE' is selected; \
remove .venv (rm -rf .venv) and rerun, or set MLKM_ROS_UNDERLAY"
  fi
else
  PY=$(find_python) || die "CPython 3.12 not found. Install it (e.g. 'pyenv install 3.12.1', or \
'apt install python3.12-venv') or set MLKM_PYTHON=/path/to/python3.12."
  log "creating .venv with $PY ($MODE)"
  rm -rf "$VENV"
  venv_args=()
  [[ -n $UNDERLAY ]] && venv_args+=(--system-site-packages)
  "$PY" -m venv "${venv_args[@]}" "$VENV" || die "python -m venv failed (on Debian/Ubuntu: \
apt install python3.12-venv)"
  echo "$UNDERLAY" >"$VENV/mlkm-underlay"
fi
VPY=$VENV/bin/python
# The wheels' bootstrapper re-executes every Python start to set LD_LIBRARY_PATH; env.sh sets
# both up front. Source it without the overlay (the workspace is rebuilt below).
export MLKM_ENV_NO_OVERLAY=1
# shellcheck source=../env.sh
source "$ROOT/env.sh" >/dev/null
unset MLKM_ENV_NO_OVERLAY

# --- 2. pip -------------------------------------------------------------------------------------
if [[ -n $UNDERLAY ]]; then
  # Only the non-ROS dependencies; ROS, colcon and its tools (empy, catkin_pkg, lark) come
  # with the underlay, whose versions they must match. The full pin list stays the
  # constraint for whatever else gets pulled in.
  REQ_USED=$VENV/requirements.underlay.txt
  sed -n '/^# --- build tools and project dependencies ---$/,/^$/p' "$REQ" \
    | grep -v -E '^(colcon-common-extensions|setuptools)==' >"$REQ_USED"
  PIP_ARGS=(-r "$REQ_USED" -c <(grep -v -E '^(ros-|colcon|empy|EmPy|catkin-pkg|lark-parser)' "$REQ"))
else
  REQ_USED=$REQ
  PIP_ARGS=(-r "$REQ")
fi
pip_stamp=$( { cat "$REQ"; echo "$MODE"; "$VPY" -VV; } | hash_of)
if [[ $FORCE == 1 || ! -f $VENV/.mlkm-pip-stamp || $(<"$VENV/.mlkm-pip-stamp") != "$pip_stamp" ]]; then
  log "pip install -r $(basename "$REQ_USED") (this takes a few minutes the first time)"
  # (This machine's pip.conf adds local file:// indexes that warn for every package they lack.)
  "$VPY" -m pip install --disable-pip-version-check --no-input -q "${PIP_ARGS[@]}" 2>&1 \
    | { grep -v -E "^WARNING: Location 'file://.*' is ignored" || true; } \
    || die 'pip install failed (see above)'
  echo "$pip_stamp" >"$VENV/.mlkm-pip-stamp"
  # New ros_*.libs directories may have appeared: recompute the environment.
  export MLKM_ENV_NO_OVERLAY=1
  source "$ROOT/env.sh" >/dev/null
  unset MLKM_ENV_NO_OVERLAY
else
  log 'python packages up to date'
fi

# --- 3. CMake paths of the wheels ---------------------------------------------------------------
if [[ -z $UNDERLAY ]]; then
  "$VPY" "$ROOT/scripts/fix_cmake_paths.py" "$VENV" | sed 's/^/setup: /'
fi

"$VPY" -c 'import colcon_core' 2>/dev/null \
  || die "colcon is not importable by $VPY (with /opt/ros/jazzy: apt install \
python3-colcon-common-extensions)"
# colcon run by the venv's Python, so that the packages' executables get it as interpreter.
COLCON=("$VPY" -c 'import sys; from colcon_core.command import main; sys.exit(main())')

# --- 4. tests only: the real ros2 command-line tools -----------------------------------------------
# `ros2 launch`, `ros2 node/topic/param/interface` are not on PyPI. The tests check the product
# against them: the upstream Jazzy sources in ../shared/vendor (MLKM_ROS2_VENDOR=<dir> to point
# elsewhere) are installed into build/ros2_tools, never into .venv, and only the tests put them
# on the paths (scripts/ros2_tools.sh). The product runs without them.
VENDOR=${MLKM_ROS2_VENDOR:-$ROOT/../shared/vendor}
TOOLS=$ROOT/build/ros2_tools
if [[ -n $UNDERLAY ]]; then
  log "ros2 tools: from $UNDERLAY"
elif ! compgen -G "$VENDOR/*.tar.gz" >/dev/null; then
  log "ros2 tools: no $VENDOR; the tests that need ros2 launch and ros2cli will skip"
else
  tools_stamp=$( {
    (cd "$VENDOR" && sha256sum ./*.tar.gz)
    "$VPY" -VV
    echo "$pip_stamp"
  } | hash_of)
  if [[ $FORCE != 1 && -f $TOOLS/.mlkm-stamp && $(<"$TOOLS/.mlkm-stamp") == "$tools_stamp" ]]; then
    log 'ros2 tools up to date'
  else
    log "ros2 tools: installing ros2cli and launch from $VENDOR into build/ros2_tools"
    rm -rf "$TOOLS"
    mkdir -p "$TOOLS/src"
    for t in "$VENDOR"/*.tar.gz; do
      n=$(basename "$t" .tar.gz)
      mkdir -p "$TOOLS/src/$n"
      tar -xzf "$t" -C "$TOOLS/src/$n"
    done
    # The pure-Python packages (each has a setup.py), in one pip call: with --target, pip moves
    # every package's files (bin/, share/ament_index/...) into the one prefix.
    mapfile -t py_pkgs < <(find "$TOOLS/src" -mindepth 3 -maxdepth 4 -name setup.py \
      -not -path '*/test/*' -printf '%h\n' | LC_ALL=C sort)
    ((${#py_pkgs[@]})) || die "ros2 tools: no setup.py under $TOOLS/src"
    "$VPY" -m pip install --disable-pip-version-check --no-input -q --no-deps \
      --no-build-isolation --target "$TOOLS/python" "${py_pkgs[@]}" 2>&1 \
      | { grep -v -E "^WARNING: Location 'file://.*' is ignored" || true; } \
      || die 'ros2 tools: pip install failed (see above)'
    # composition_interfaces (launch_ros imports it) is a message package: colcon, as ros2_ws.
    msg_pkg=$(find "$TOOLS/src" -mindepth 3 -maxdepth 3 -type d -name composition_interfaces)
    [[ -n $msg_pkg ]] || die "ros2 tools: no composition_interfaces under $TOOLS/src"
    (cd "$TOOLS" && "${COLCON[@]}" --log-base "$TOOLS/log" --log-level error build \
      --base-paths "$msg_pkg" --build-base "$TOOLS/build" --install-base "$TOOLS/install" \
      --merge-install --event-handlers desktop_notification- terminal_title- status- \
      --cmake-args -DPython3_EXECUTABLE="$VPY" -DBUILD_TESTING=OFF -Wno-dev \
      >"$TOOLS/colcon.out" 2>&1) \
      || { tail -n 40 "$TOOLS/colcon.out"; die "ros2 tools: colcon build of composition_interfaces \
failed (log: build/ros2_tools/colcon.out)"; }
    echo "$tools_stamp" >"$TOOLS/.mlkm-stamp"
    log 'ros2 tools: done (tests source scripts/ros2_tools.sh)'
  fi
fi

# --- 5. colcon build -------------------------------------------------------------------------------
# What needs a rebuild: any file added or removed, or a changed non-Python file (msg, CMake,
# package.xml, setup.cfg, config) or setup.py. Edits of Python modules need none: the build is
# a --symlink-install (develop mode), so the overlay runs the sources.
src_files() {  # files of ros2_ws/src, NUL-separated, sorted; extra find tests in "$@"
  (cd "$WS/src" && find . \( -name __pycache__ -o -name '*.egg-info' -o -name .pytest_cache \) \
    -prune -o -type f ! -name '*.pyc' "$@" -print0 | LC_ALL=C sort -z)
}
src_stamp=$( {
  echo "$pip_stamp"
  src_files | tr '\0' '\n'
  src_files \( ! -name '*.py' -o -name setup.py \) | (cd "$WS/src" && xargs -0 -r sha256sum)
} | hash_of)
# The stamp also names colcon's log of our build: a colcon build run by hand since then (say,
# without --symlink-install) may have changed the install, so rebuild after it.
BUILD_STAMP=$WS/install/.mlkm-build-stamp
last_build() { readlink "$WS/log/latest_build" 2>/dev/null || true; }
if [[ $FORCE != 1 && -f $BUILD_STAMP && $(<"$BUILD_STAMP") == "$src_stamp $(last_build)" ]]; then
  log 'ros2_ws up to date'
  exit 0
fi
log "colcon build of ros2_ws (log: ros2_ws/log/latest_build)"
rm -f "$BUILD_STAMP"
cd "$WS"
mkdir -p "$WS/log"
colcon_out=$WS/log/mlkm-colcon.out
rc=0
"${COLCON[@]}" --log-level error build --symlink-install --continue-on-error \
  --event-handlers desktop_notification- terminal_title- status- \
  --cmake-args -DPython3_EXECUTABLE="$VPY" -DBUILD_TESTING=OFF -Wno-dev \
  2>&1 | tee "$colcon_out" || rc=$?
if ((rc != 0)); then
  for pkg in $(sed -n 's/^Failed *<<< \([^ ]*\).*/\1/p' "$colcon_out"); do
    f=$WS/log/latest_build/$pkg/stdout_stderr.log
    printf '\n----- %s failed; the end of %s:\n' "$pkg" "${f#"$ROOT"/}"
    tail -n 40 "$f" 2>/dev/null || true
  done
  die "colcon build failed (exit $rc); full logs in ros2_ws/log/latest_build/<package>/"
fi
echo "$src_stamp $(last_build)" >"$BUILD_STAMP"
log 'done'
