#!/usr/bin/env bash
# Idempotent set-up of aruco_abs_orient on Debian 12 (run as root, or with passwordless sudo):
#   1. Debian's ROS 1 packages (apt, only when one is missing),
#   2. the venv .venv (/usr/bin/python3 --system-site-packages) with the pinned requirements,
#   3. the real robot_localization, built by ../shared/tools/build-robot-localization into one workspace per
#      machine (~/.cache/aruco_abs_orient/robot_localization), in the background while steps 2 and 5 install,
#   4. the catkin workspace $WS (the repository linked as $WS/src/aruco_abs_orient), built with
#      the venv's python. $WS is outside the repository (tools/paths.sh says why and where).
#   5. the venv .venv-noetic: a Python 3.8 (pyenv's, or python3.8 on PATH; $AAO_PYTHON38 overrides)
#      with a Noetic robot's versions (requirements-noetic.txt), for test/test_noetic.py. Without a
#      Python 3.8 it warns and goes on (that test then fails and says how to get one).
# Each step is skipped when a stamp says nothing it depends on changed, so a repeated run takes
# seconds. No `set -u`: catkin's setup.bash reads unset variables.
set -eo pipefail
ROOT=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")/.." && pwd -P)
cd "$ROOT"
# Debian's python3 must win over pyenv & co.: ROS 1's python modules exist only for /usr/bin/python3.
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH
unset PYTHONPATH PYTHONHOME PYENV_VERSION CMAKE_PREFIX_PATH ROS_PACKAGE_PATH
export DEBIAN_FRONTEND=noninteractive
# shellcheck disable=SC1091
source "$ROOT/tools/paths.sh"
WS=$(aao_workspace "$ROOT")
STAMPS=$WS/stamps
mkdir -p "$STAMPS"
log() { echo "setup: $*" >&2; }
t_start=$(date +%s.%N)
elapsed() { awk -v a="$t_start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }'; }

# --------------------------------------------------------------------------- 1. apt
APT_PKGS=(
  python3-rospy python3-roslaunch python3-rosmaster rosout python3-rostest librostest-dev
  python3-tf2-ros python3-std-msgs python3-geometry-msgs python3-nav-msgs python3-sensor-msgs
  python3-tf2-msgs python3-visualization-msgs python3-diagnostic-msgs python3-diagnostic-updater python3-cv-bridge
  python3-dynamic-reconfigure libdynamic-reconfigure-config-init-mutex-dev python3-rosbag
  catkin catkin-lint python3-venv tf2-tools python3-rostopic python3-rosnode python3-rosservice rosbash
  ros-std-msgs ros-geometry-msgs ros-sensor-msgs ros-nav-msgs ros-diagnostic-msgs ros-visualization-msgs
  ros-message-generation ros-message-runtime python3-genpy python3-gencpp python3-genmsg g++ make
  libjpeg62-turbo-dev  # process's row decoder (detection/jpegrows.c, compiled on first use)
)
missing=$(dpkg-query -W -f='${Package} ${db:Status-Status}\n' "${APT_PKGS[@]}" 2>/dev/null |
  awk '$2 == "installed" { print $1 }' | sort | comm -13 - <(printf '%s\n' "${APT_PKGS[@]}" | sort)) || true
if [[ -n "$missing" ]]; then
  log "installing Debian packages: $(echo $missing)"
  SUDO=()
  ((EUID == 0)) || SUDO=(sudo -n env DEBIAN_FRONTEND=noninteractive)
  "${SUDO[@]}" apt-get update -q -o DPkg::Lock::Timeout=600 >&2
  # shellcheck disable=SC2086
  "${SUDO[@]}" apt-get install -y -q --no-install-recommends -o DPkg::Lock::Timeout=600 $missing >&2
else
  log "Debian packages: all ${#APT_PKGS[@]} present"
fi

# --------------------------------------------------------------------------- 3. robot_localization (started)
# the shared tools next to the repository (../shared), or where $AAO_SHARED says, or this machine's /work/shared
RL_TOOL=
for shared in "${AAO_SHARED:-}" "$ROOT/../shared" /work/shared; do
  if [[ -n $shared && -x $shared/tools/build-robot-localization ]]; then
    RL_TOOL=$shared/tools/build-robot-localization
    break
  fi
done
# Built in the background while the venvs install (its C++ build keeps both cores busy for minutes; pip
# mostly unpacks), into one workspace per machine: it does not depend on the checkout, so another clone or
# worktree finds it built (the tool keeps it up to date by a fingerprint of its sources and Debian's packages,
# and locks it while it builds). AAO_RL_WS names another.
RL_WS=${AAO_RL_WS:-${HOME:-/root}/.cache/aruco_abs_orient/robot_localization}
RL_OUT=$STAMPS/rl_build.out
RL_PID=
if [[ -n $RL_TOOL ]]; then
  "$RL_TOOL" "$RL_WS" >"$RL_OUT" 2>"$RL_OUT.log" &
  RL_PID=$!
fi


# --------------------------------------------------------------------------- 2. venv
VENV=$ROOT/.venv
if [[ ! -x $VENV/bin/python ]] || ! grep -q '^include-system-site-packages = true' "$VENV/pyvenv.cfg" ||
  [[ "$(readlink -f "$VENV/bin/python")" != /usr/bin/python3* ]]; then
  log "creating the venv $VENV from /usr/bin/python3 (--system-site-packages: sees Debian's ROS 1)"
  rm -rf -- "$VENV"
  /usr/bin/python3 -m venv --system-site-packages "$VENV"
  rm -f -- "$STAMPS/venv"
fi
want=$(cat requirements.txt setup.py | sha256sum | cut -d' ' -f1)
if [[ "$(cat "$STAMPS/venv" 2>/dev/null)" != "$want" ]]; then
  log "installing Python requirements into $VENV"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check -r requirements.txt 2>&1 |
    grep -v 'is ignored: it is neither a file nor a directory' >&2 || true
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e . 2>&1 |
    grep -v 'is ignored: it is neither a file nor a directory' >&2 || true
  "$VENV/bin/python" -c 'import numpy, cv2, rosbags, serial, cv_bridge, rospy, aruco_abs_orient' ||
    { log "ERROR: the venv cannot import its requirements (see above)"; exit 1; }
  echo "$want" >"$STAMPS/venv"
else
  log "venv: up to date"
fi

# --------------------------------------------------------------------------- 5. .venv-noetic
# Every Python 3.8 interpreter we can see, the newest patch release first: $AAO_PYTHON38, pyenv's
# versions (pyenv root, $PYENV_ROOT, ~/.pyenv), python3.8 on PATH (a pyenv shim only works when pyenv
# selects 3.8: each candidate is asked for its version and its real path).
find_python38() {
  local roots=() c
  command -v pyenv >/dev/null 2>&1 && roots+=("$(pyenv root 2>/dev/null)")
  roots+=("${PYENV_ROOT:-}" "${HOME:-/root}/.pyenv")
  {
    [[ -n ${AAO_PYTHON38:-} ]] && echo "$AAO_PYTHON38"
    for c in "${roots[@]}"; do
      [[ -n $c ]] && printf '%s\n' "$c"/versions/3.8*/bin/python3.8
    done | sort -rV
    command -v python3.8 2>/dev/null
  } | while read -r c; do
    [[ -x $c ]] && "$c" -c 'import sys, venv; assert sys.version_info[:2] == (3, 8); print(sys.executable)' 2>/dev/null
  done | head -n 1 || true
}
NVENV=$ROOT/.venv-noetic
want=$(cat requirements-noetic.txt setup.py | sha256sum | cut -d' ' -f1)
if [[ -x $NVENV/bin/python && "$(cat "$STAMPS/venv-noetic" 2>/dev/null)" == "$want" ]]; then
  log "venv-noetic: up to date"
else
  rm -f -- "$STAMPS/venv-noetic"
  PY38=$(find_python38)
  if [[ -z $PY38 ]]; then
    log "WARNING: no Python 3.8 found (\$AAO_PYTHON38, \$(pyenv root)/versions/3.8*, ~/.pyenv/versions/3.8*," \
      "python3.8 on PATH): .venv-noetic not built and test/test_noetic.py will fail. Get one with" \
      "'pyenv install 3.8' (or on Ubuntu 20.04: apt install python3.8-venv), then run make setup again."
  else
    if [[ ! -x $NVENV/bin/python ]] || [[ "$("$NVENV/bin/python" -c 'import sys; print(sys.version_info[:2] == (3, 8))' \
      2>/dev/null)" != True ]]; then
      log "creating the venv $NVENV from $PY38 (a Noetic robot's Python stack)"
      rm -rf -- "$NVENV"
      "$PY38" -m venv "$NVENV"
      echo '*' >"$NVENV/.gitignore"
    fi
    log "installing requirements-noetic.txt into $NVENV"
    "$NVENV/bin/python" -m pip install -q --disable-pip-version-check -r requirements-noetic.txt 2>&1 |
      grep -v 'is ignored: it is neither a file nor a directory\|DEPRECATION: PyYAML is being installed' >&2 || true
    "$NVENV/bin/python" -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e . 2>&1 |
      grep -v 'is ignored: it is neither a file nor a directory' >&2 || true
    if "$NVENV/bin/python" -c 'import numpy, cv2, yaml, serial, scipy, matplotlib, rosbags, pytest, hypothesis
import aruco_abs_orient.offline.cli' && "$NVENV/bin/python" -m pip check -q >&2; then
      echo "$want" >"$STAMPS/venv-noetic"
    else
      log "WARNING: $NVENV cannot import its requirements (see above): test/test_noetic.py will fail"
    fi
  fi
fi
# --------------------------------------------------------------------------- 3. robot_localization (the end)
RL_SETUP=
if [[ -n $RL_PID ]]; then
  rl_status=0
  wait "$RL_PID" || rl_status=$?
  cat "$RL_OUT.log" >&2
  ((rl_status == 0)) || { log "ERROR: building robot_localization failed (exit $rl_status; above)"; exit 1; }
  RL_SETUP=$(tail -n 1 "$RL_OUT")
  log "robot_localization: $RL_SETUP"
else
  log "robot_localization: no build-robot-localization in \$AAO_SHARED/tools, $ROOT/../shared/tools or" \
    "/work/shared/tools: not built (the EKF rostest will fail and make demo skips the EKF; on a ROS distro" \
    "install ros-\$ROS_DISTRO-robot-localization)"
fi
echo "$RL_SETUP" >"$STAMPS/rl_setup"

# --------------------------------------------------------------------------- 4. catkin workspace
mkdir -p "$WS/src"
if [[ "$(readlink -f "$WS/src/aruco_abs_orient" 2>/dev/null)" != "$ROOT" ]]; then
  rm -rf -- "$WS/src/aruco_abs_orient"
  ln -s "$ROOT" "$WS/src/aruco_abs_orient"
fi
[[ -f $WS/src/CMakeLists.txt ]] || ln -sf /usr/share/catkin/cmake/toplevel.cmake "$WS/src/CMakeLists.txt"
want=$( {
  echo "$RL_SETUP"
  cat CMakeLists.txt package.xml setup.py msg/*.msg
  ls scripts test/*.test 2>/dev/null
  [[ -d cfg ]] && find cfg -name '*.cfg' -exec cat {} +
} | sha256sum | cut -d' ' -f1)
if [[ "$(cat "$STAMPS/catkin" 2>/dev/null)" != "$want" || ! -f $WS/devel/setup.bash ]]; then
  log "building the catkin workspace $WS (log: $WS/build.log)"
  if [[ -n $RL_SETUP ]]; then
    # shellcheck disable=SC1090
    source "$RL_SETUP"
  else
    # shellcheck disable=SC1091
    source /usr/share/catkin/setup.bash 2>/dev/null || true
  fi
  CMAKE_ARGS=(-DPYTHON_EXECUTABLE="$VENV/bin/python" -DCMAKE_BUILD_TYPE=Release)
  # a build/ configured for another python or another underlay is useless: start over
  if [[ -f $WS/build/CMakeCache.txt ]] && ! grep -qxF "PYTHON_EXECUTABLE:FILEPATH=$VENV/bin/python" \
    "$WS/build/CMakeCache.txt"; then
    rm -rf -- "$WS/build" "$WS/devel"
  fi
  if ! (cd "$WS" && catkin_make "${CMAKE_ARGS[@]}" </dev/null) >"$WS/build.log" 2>&1; then
    tail -n 40 "$WS/build.log" >&2
    log "ERROR: catkin_make failed; full log: $WS/build.log"
    exit 1
  fi
  echo "$want" >"$STAMPS/catkin"
else
  log "catkin workspace: up to date"
fi
log "done in $(elapsed) s"
