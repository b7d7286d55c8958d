#!/usr/bin/env bash
# make demo: the main job on the embedded demo scenario, as a user would run it on a recording:
#   1. generate the demo scenario (60 s, 30 fps, 3840x1920, 19 cm markers at 2-12 m; cached in
#      .cache/demo/scenario — DEMO_FORCE=1 re-renders it; DEMO_PRESET=ci for a quick look),
#   2. estimate the camera <-> total-station time offset (timesync),
#   3. process the bag (detection -> per-marker yaw -> map->odom filter -> trajectory),
#   4. evaluate against the hidden truth: report (Markdown + JSON) and plots.
set -eo pipefail
ROOT=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")/.." && pwd -P)
PRESET=${DEMO_PRESET:-demo}
OUT=${DEMO_OUT:-$ROOT/.cache/$PRESET}
SCEN=$OUT/scenario
RUN=$OUT/run
step() { printf '\n\033[1m== %s\033[0m\n' "$*"; }

step "1/4 scenario ($PRESET preset)"
if [[ -f $SCEN/scenario.bag && -f $SCEN/hidden.yaml && ${DEMO_FORCE:-0} != 1 ]]; then
  echo "using the cached scenario $SCEN (DEMO_FORCE=1 make demo renders it again)"
else
  aruco-abs-orient-synth --preset "$PRESET" --out "$SCEN" --force
fi

step "2/4 time offset between camera and total station"
mkdir -p "$RUN"
aruco-abs-orient timesync "$SCEN/scenario.bag" --plot "$RUN" | tee "$RUN/timesync.txt"
OFFSET=$(sed -n 's/.*--time-offset \([-0-9.]*\).*/\1/p' "$RUN/timesync.txt")
TRUE_OFFSET=$(python -c "import yaml,sys; print(yaml.safe_load(open(sys.argv[1]))['camera_time_offset'])" \
  "$SCEN/hidden.yaml")
echo "(the scenario's hidden offset: $TRUE_OFFSET s)"

step "3/4 process the bag with the estimated offset"
aruco-abs-orient process "$SCEN/scenario.bag" --markers "$SCEN/markers.yaml" --out "$RUN" --time-offset "$OFFSET"

step "4/4 evaluate against the truth"
aruco-abs-orient evaluate "$RUN" --reference "$SCEN/truth.tum" --overview "$SCEN/scenario.bag" "$SCEN/markers.yaml"

printf '\n\033[1mdemo outputs\033[0m in %s:\n' "$RUN"
(cd "$RUN" && ls -1 trajectory.tum observations.csv summary.json report.md report.json ./*.png)
echo "open $RUN/report.md for the figures and plots"
