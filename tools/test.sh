#!/usr/bin/env bash
# make test: every test, in two pytest runs on two workers each (pytest-xdist; test/conftest.py keeps a
# test file on one worker).
#   1. the rostests (test/test_rostests.py) one after another on one worker: each has a real roscore,
#      replays in real time and checks timing (lookups at now, recovery times); beside them, on the other,
#      the Python 3.8 run of the core tests (test/test_noetic.py: mostly it waits on simulated instruments
#      and clocks);
#   2. the unit tests.
# Arguments go to both runs (e.g. -k name, --durations=20); a run that selects nothing is not a failure.
# Exit status: 0 when both pass.
set -u
cd "$(dirname "$0")/.."
status=0
python -m pytest test/test_rostests.py test/test_noetic.py -n 2 --dist loadgroup "$@" || [ $? -eq 5 ] || status=1
python -m pytest test --ignore=test/test_rostests.py --ignore=test/test_noetic.py -n 2 --dist loadgroup "$@" ||
  [ $? -eq 5 ] || status=1
exit $status
