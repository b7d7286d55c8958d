#!/usr/bin/env bash
# make demo: the main job on a rendered recording, as a user would run it on theirs (about 4 minutes on 2 cores):
#   1. generate the scenario (default: the realistic world's 30 s calibration run, preset `calibration-rs`:
#      30 fps, 3840x1920, 19 cm markers at 2-12 m in a hall with pillars, posters and lights, a VO drifting in
#      yaw and tilt, a wandering platform and a 30 ms rolling shutter, a 360° spin in place beside 4 markers,
#      then 19 s of the drive; cached in .cache/<preset>/scenario — DEMO_FORCE=1 re-renders it;
#      DEMO_PRESET=demo for the full 60 s drive (about 9 minutes), DEMO_PRESET=easy for the easy world,
#      DEMO_PRESET=ci for a 20 s, 1920x960 quick look),
#   2. estimate the camera <-> total-station time offset (timesync, from the VO heading; when the recording's
#      turns do not determine it, from the marker bearings: timesync --markers, as its message advises),
#   3. calibrate the camera's mounting rotation (boresight) from the bag and refine the time offset
#      with the marker bearings, then process the bag
#      with it (detection -> per-marker yaw -> map->odom filter -> trajectory),
#   4. replay the bag through the ROS node and the real robot_localization EKF
#      (roslaunch aruco_abs_orient postprocess.launch use_ekf:=true), recording the outputs,
#   5. the report (Markdown + JSON, plots): what the run shows by itself, and the errors of both against the
#      scenario's truth (its reference trajectory; the report's other figures need none);
#   then, with DEMO_VIDEO=1, the video path: the same scenario as a camera user has it (MP4 + VO trajectory +
#   prism CSV, no bag): timesync over the separate clocks, process, the heading against the truth.
# Each step says how long it took, the end how long the demo took.
set -eo pipefail
ROOT=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")/.." && pwd -P)
PRESET=${DEMO_PRESET:-calibration-rs}
OUT=${DEMO_OUT:-$ROOT/.cache/$PRESET}
SCEN=$OUT/scenario
RUN=$OUT/run
T0=$SECONDS
T_STEP=
step() {  # the previous step's time, then the next step's title
  [[ -z $T_STEP ]] || printf '(%d s)\n' "$((SECONDS - T_STEP))"
  printf '\n\033[1m== %s\033[0m\n' "$*"
  T_STEP=$SECONDS
}

step "1/5 scenario ($PRESET preset)"
same_preset() {  # the cached scenario was made from this preset (not an older generator's or another preset's)
  python -c "import sys; from aruco_abs_orient.synthetic.scenario import PRESETS, ScenarioConfig as C; import yaml; \
sys.exit(C.from_dict(yaml.safe_load(open(sys.argv[1]))['config']) != PRESETS[sys.argv[2]])" "$SCEN/hidden.yaml" \
    "$PRESET" 2>/dev/null
}
if [[ -f $SCEN/scenario.bag && -f $SCEN/hidden.yaml && ${DEMO_FORCE:-0} != 1 ]] && same_preset; then
  echo "using the cached scenario $SCEN (DEMO_FORCE=1 make demo renders it again)"
else
  aruco-abs-orient-synth --preset "$PRESET" --out "$SCEN" --force
fi

step "2/5 time offset between camera and total station"
mkdir -p "$RUN"
TRUE_OFFSET=$(python -c "import yaml,sys; print(yaml.safe_load(open(sys.argv[1]))['camera_time_offset'])" \
  "$SCEN/hidden.yaml")
if aruco-abs-orient timesync "$SCEN/scenario.bag" --plot "$RUN" | tee "$RUN/timesync.txt" ||
  { echo "the VO heading alone does not determine it here: from the marker bearings (timesync --markers)"
    aruco-abs-orient timesync "$SCEN/scenario.bag" --markers "$SCEN/markers.yaml" --plot "$RUN" | tee "$RUN/timesync.txt"; }
then
  OFFSET=$(sed -n 's/.*--time-offset \([-0-9.]*\).*/\1/p' "$RUN/timesync.txt")
  echo "(the scenario's hidden offset: $TRUE_OFFSET s)"
else
  OFFSET=$TRUE_OFFSET
  echo "this recording does not determine the offset (see above): the demo goes on with the scenario's" \
    "known offset, $OFFSET s"
fi

step "3/5 calibrate the boresight and refine the time offset with the marker bearings, then process the bag"
CAL=()
CALFILE=
# the camera's rolling shutter is a property its user knows: its readout is estimated when it has one; calibrate
# also estimates the camera's two lenses and chooses the platform model by the data (its defaults), and draws its
# residuals before and after (calibration.png, in the report)
READOUT=()
python -c "import yaml,sys; sys.exit(not yaml.safe_load(open(sys.argv[1]))['config'].get('rolling_shutter_readout'))" \
  "$SCEN/hidden.yaml" && READOUT=(--readout)
if aruco-abs-orient calibrate "$SCEN/scenario.bag" --markers "$SCEN/markers.yaml" --time-offset "$OFFSET" \
  --refine-time-offset "${READOUT[@]}" --every 3 --out "$RUN/calibration.yaml" --plot "$RUN" \
  | tee "$RUN/calibration.txt"; then
  CALFILE=$RUN/calibration.yaml
  CAL=(--calibration "$CALFILE")
  REFINED=$(sed -n 's/.*--time-offset \([-0-9.]*\).*/\1/p' "$RUN/calibration.txt")
  OFFSET=${REFINED:-$OFFSET}
  python -c "import yaml,sys; b=yaml.safe_load(open(sys.argv[1]))['boresight']['rpy_deg']; \
print('(the scenario\'s hidden boresight error, roll pitch yaw: %.4f %.4f %.4f deg; hidden time offset %s s)' \
% (tuple(b) + (sys.argv[2],)))" "$SCEN/hidden.yaml" "$TRUE_OFFSET"
else
  echo "no calibration from this recording (see above): processing with the bag's own lever arms"
fi
aruco-abs-orient process "$SCEN/scenario.bag" --markers "$SCEN/markers.yaml" --out "$RUN" --time-offset "$OFFSET" \
  "${CAL[@]}"

step "4/5 the ROS node and robot_localization on the bag (postprocess.launch, played at its own speed)"
FUSED=()
if rospack find robot_localization >/dev/null 2>&1; then
  rm -f "$RUN/fused.bag"
  # its own master on a free port, so a roscore already running is not disturbed
  PORT=$(python -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
  ROS_MASTER_URI=http://localhost:$PORT roslaunch -p "$PORT" aruco_abs_orient postprocess.launch \
    bag:="$SCEN/scenario.bag" markers:="$SCEN/markers.yaml" use_ekf:=true time_offset:="$OFFSET" calibration:="$CALFILE" \
    record:="$RUN/fused.bag" >"$RUN/postprocess.log" 2>&1 || true
  grep -a "replay: " "$RUN/postprocess.log" | sed 's/^.*\(replay: \)/\1/' || true
  if [[ -f $RUN/fused.bag ]]; then
    # evaluate reads the clock offset from the run's summary.json and judges the EKF from 1 s after its
    # first absolute yaw (the end of the standstill), as a user's run would be judged
    FUSED=(--fused "$RUN/fused.bag")
    echo "recorded the node's and the EKF's outputs: $RUN/fused.bag (log: $RUN/postprocess.log)"
  else
    echo "postprocess.launch recorded nothing; see $RUN/postprocess.log"
  fi
else
  echo "robot_localization is not installed here: skipped (on a ROS distro: apt install ros-\$ROS_DISTRO-robot-localization)"
fi

step "5/5 the report (and the errors against the scenario's truth)"
aruco-abs-orient evaluate "$RUN" --reference "$SCEN/truth.tum" "${FUSED[@]}" \
  --overview "$SCEN/scenario.bag" "$SCEN/markers.yaml"

if [[ ${DEMO_VIDEO:-0} != 0 ]]; then
  step "video path: the scenario as MP4 + VO trajectory + prism CSV, timesync, process (no bag)"
  VID=$OUT/video
  [[ -f $VID/truth.tum && ${DEMO_FORCE:-0} != 1 ]] || python -m aruco_abs_orient.synthetic.export "$SCEN" --out "$VID"
  IN=(--video "$VID/video.mp4" --trajectory "$VID/vo.tum" --prism "$VID/prism.csv" --lever-arms "$VID/lever_arms.yaml")
  aruco-abs-orient timesync "${IN[@]}" --markers "$VID/markers.yaml" --quiet | tee "$VID/timesync.txt"
  VOFFSET=$(sed -n 's/.*--time-offset \([-0-9.]*\).*/\1/p' "$VID/timesync.txt")
  aruco-abs-orient process "${IN[@]}" --markers "$VID/markers.yaml" --out "$VID/run" --time-offset "$VOFFSET" \
    "${CAL[@]}" --quiet
  aruco-abs-orient evaluate "$VID/run" --reference "$VID/truth.tum" | grep -i "heading" || true
fi

printf '(%d s)\n\n\033[1mdemo outputs\033[0m in %s (the demo took %d min %d s):\n' "$((SECONDS - T_STEP))" "$RUN" \
  "$(((SECONDS - T0) / 60))" "$(((SECONDS - T0) % 60))"
(cd "$RUN" && ls -1 trajectory.tum observations.csv summary.json report.md report.json ./*.png)
echo "open $RUN/report.md for the figures and plots"
