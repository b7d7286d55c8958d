#!/usr/bin/env bash
# make demo: generate the demo scenario (cached under .cache/demo; DEMO_FORCE=1 re-renders) and show it.
set -eo pipefail
ROOT=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")/.." && pwd -P)
OUT=${DEMO_OUT:-$ROOT/.cache/demo}
SCEN=$OUT/scenario
if [[ -f $SCEN/scenario.bag && ${DEMO_FORCE:-0} != 1 ]]; then
  echo "demo: using the cached scenario $SCEN (DEMO_FORCE=1 make demo re-renders it)"
else
  aruco-abs-orient-synth --preset demo --out "$SCEN" --force
fi
echo "demo: scenario in $SCEN:"
ls -l "$SCEN"
