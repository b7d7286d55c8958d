#!/usr/bin/env bash
# make test: every test, in one pytest run on four workers (pytest-xdist; test/conftest.py groups the tests):
#   - the rostests in two lanes side by side (each lane one rostest after another: each has a real roscore on
#     its own port, replays in real time and checks timing: lookups at now, recovery times);
#   - beside them the Python 3.8 run of the core tests (test/test_noetic.py), in two parts side by side;
#   - the unit tests, taken by whichever worker is free (a lane that has finished takes unit tests).
# The scenarios the tests render are rendered once per run, in a directory every pytest process of the run
# shares ($AAO_TEST_SCENARIOS: the Python 3.8 run and the unit tests render each scenario once between them;
# the rostests keep theirs in .cache/rostest, keyed by the renderer's sources).
# Arguments go to pytest (e.g. -k name, --durations=20); a run that selects nothing is not a failure.
# Exit status: 0 when everything passes.
set -u
cd "$(dirname "$0")/.."
# OpenBLAS's threads, one per core, spin while they wait: the tests' small matrices (3x3 inverses of the filter)
# then cost milliseconds instead of microseconds on a busy machine (the Monte Carlo test of the filter's
# covariance 249 s instead of 14 s at load 10). The package sets this itself, but only when it is imported
# before numpy, which pytest's workers do not guarantee; test_blas_threads clears it to check the scripts.
export OPENBLAS_NUM_THREADS=${OPENBLAS_NUM_THREADS:-1}
if [[ -z ${AAO_TEST_SCENARIOS:-} ]]; then
  AAO_TEST_SCENARIOS=$(mktemp -d "${TMPDIR:-/tmp}/aao-test-scenarios.XXXXXX")
  trap 'rm -rf -- "$AAO_TEST_SCENARIOS"' EXIT
fi
export AAO_TEST_SCENARIOS
status=0
python -m pytest test -n 4 --dist loadgroup "$@" || [ $? -eq 5 ] || status=1
exit $status
