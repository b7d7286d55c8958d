#!/usr/bin/env bash
# make screenshot: rviz with rviz/abs_orient.rviz during a replay, captured headless (Xvfb, software GL) into
# doc/images/rviz.png — tf, the marker map, the bearing rays, the prism track, the EKF's odometry, the debug image.
#   - installs rviz, xvfb and imagemagick with apt when missing (on demand only: `make setup` does not, they
#     would slow a fresh `make test`);
#   - the recording: SCREENSHOT_SCENARIO=<dir> (a generated scenario: scenario.bag, markers.yaml, hidden.yaml);
#     default the demo scenario when `make demo` has rendered it (.cache/easy/scenario), else the ci preset
#     rendered once into .cache/screenshot/scenario (about 2 minutes);
#   - SCREENSHOT_AT=<s>: wall seconds after playback starts (default 22), SCREENSHOT_OUT=<png>.
# Replays with `roslaunch aruco_abs_orient postprocess.launch use_ekf:=true rviz:=true` on its own master.
set -eo pipefail
ROOT=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")/.." && pwd -P)
AT=${SCREENSHOT_AT:-22}
OUT=${SCREENSHOT_OUT:-$ROOT/doc/images/rviz.png}
log() { printf 'screenshot: %s\n' "$*" >&2; }

missing=()
for pkg in rviz xvfb imagemagick; do
  dpkg-query -W -f='${db:Status-Status}' "$pkg" 2>/dev/null | grep -qx installed || missing+=("$pkg")
done
if ((${#missing[@]})); then
  log "installing ${missing[*]} (apt)"
  SUDO=()
  ((EUID == 0)) || SUDO=(sudo -n env DEBIAN_FRONTEND=noninteractive)
  "${SUDO[@]}" apt-get install -y -q --no-install-recommends -o DPkg::Lock::Timeout=600 "${missing[@]}" >&2
fi

SCEN=${SCREENSHOT_SCENARIO:-}
if [[ -z $SCEN ]]; then
  if [[ -f $ROOT/.cache/easy/scenario/scenario.bag ]]; then
    SCEN=$ROOT/.cache/easy/scenario
  else
    SCEN=$ROOT/.cache/screenshot/scenario
    if [[ ! -f $SCEN/scenario.bag ]]; then
      log "rendering the ci scenario into $SCEN (once)"
      aruco-abs-orient-synth --preset ci --duration 32 --out "$SCEN" --force --quiet
    fi
  fi
fi
for f in scenario.bag markers.yaml hidden.yaml; do
  [[ -f $SCEN/$f ]] || { log "$SCEN/$f is missing (SCREENSHOT_SCENARIO must be a generated scenario)"; exit 1; }
done
OFFSET=$(python -c "import yaml,sys; print(yaml.safe_load(open(sys.argv[1]))['camera_time_offset'])" "$SCEN/hidden.yaml")

DISPLAY_NUM=$((90 + RANDOM % 100))
PORT=$((20000 + RANDOM % 20000))
WORK=$(mktemp -d)
cleanup() {
  set +e  # every step runs, whatever the one before it did
  if [[ -n ${LAUNCH_PID:-} ]]; then
    kill -INT -- "-$LAUNCH_PID" 2>/dev/null && sleep 3
    kill -KILL -- "-$LAUNCH_PID" 2>/dev/null
  fi
  [[ -n ${XVFB_PID:-} ]] && kill "$XVFB_PID" 2>/dev/null
  rm -rf "$WORK"
}
trap cleanup EXIT
Xvfb ":$DISPLAY_NUM" -screen 0 1440x900x24 -nolisten tcp >"$WORK/xvfb.log" 2>&1 &
XVFB_PID=$!
export DISPLAY=":$DISPLAY_NUM" LIBGL_ALWAYS_SOFTWARE=1 ROS_HOSTNAME=localhost ROS_MASTER_URI="http://localhost:$PORT"
export ROS_HOME=$WORK
sleep 1
log "replaying $SCEN/scenario.bag with rviz on display $DISPLAY (log: $WORK/launch.log while it runs)"
setsid roslaunch -p "$PORT" aruco_abs_orient postprocess.launch bag:="$SCEN/scenario.bag" \
  markers:="$SCEN/markers.yaml" time_offset:="$OFFSET" use_ekf:=true rviz:=true >"$WORK/launch.log" 2>&1 &
LAUNCH_PID=$!
sleep "$AT"
if ! kill -0 "$LAUNCH_PID" 2>/dev/null || grep -q "process has died.*rviz\|rviz-.*died" "$WORK/launch.log"; then
  log "the replay or rviz ended early:"; tail -30 "$WORK/launch.log" >&2; exit 1
fi
mkdir -p "$(dirname "$OUT")"
import -display "$DISPLAY" -window root "$OUT"
log "wrote $OUT ($(identify -format '%wx%h' "$OUT"))"
