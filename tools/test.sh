#!/usr/bin/env bash
# make test: every test, in two pytest runs.
#   1. the rostests (test/test_rostests.py), one after another with nothing else running: each has a real
#      roscore, replays in real time and checks timing (lookups at now, recovery times);
#   2. the unit tests and the Python 3.8 run of the core tests (test/test_noetic.py) on two workers
#      (pytest-xdist; test/conftest.py keeps each test file on one worker and starts the Python 3.8 run
#      first).
# Arguments go to both runs (e.g. -k name, --durations=20); a run that selects nothing is not a failure.
# Exit status: 0 when both pass.
set -u
cd "$(dirname "$0")/.."
status=0
python -m pytest test/test_rostests.py "$@" || [ $? -eq 5 ] || status=1
python -m pytest test --ignore=test/test_rostests.py -n 2 --dist loadgroup "$@" || [ $? -eq 5 ] || status=1
exit $status
