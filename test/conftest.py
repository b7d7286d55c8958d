"""Shared pytest set-up: hypothesis profiles (no deadlines on a shared 2-core machine) and the
synthetic scenarios the pipeline tests share."""
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile("default", deadline=None, suppress_health_check=[HealthCheck.too_slow])
# CI: the same examples every run (a red build is reproducible, never a new random draw); locally random
settings.register_profile("ci", deadline=None, max_examples=50, derandomize=True,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci" if os.environ.get("CI") else "default")


@pytest.fixture(scope="session")
def scenario_factory(tmp_path_factory):
    """Generated synthetic scenarios (bag + truth), rendered once per session and shared, between the
    workers of ``-n 2`` too (a lock file per scenario): ``scenario_factory("ci", time_offset=0.2)`` →
    ``GeneratedScenario``. With ``$AAO_TEST_SCENARIOS`` (a directory: tools/test.sh makes one per ``make
    test``) they are shared by every pytest run that names it: the Python 3.8 run of the core tests and the
    unit tests render each scenario once between them."""
    import fcntl
    import hashlib
    import json
    from dataclasses import replace

    from aruco_abs_orient.synthetic.bag import GeneratedScenario, generate
    from aruco_abs_orient.synthetic.scenario import PRESETS

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("AAO_TEST_SCENARIOS"):
        root = Path(os.environ["AAO_TEST_SCENARIOS"])
    elif os.environ.get("PYTEST_XDIST_WORKER"):  # the workers' base temps share this parent
        root = root.parent
    cache = {}

    def make(preset: str, **changes):
        key = (preset, tuple(sorted(changes.items())))
        if key not in cache:
            out = root / f"scenario_{preset}_{hashlib.sha1(repr(key).encode()).hexdigest()[:10]}"
            made = out.with_suffix(".json")
            with open(str(out.with_suffix(".lock")), "w") as lock:
                fcntl.flock(lock, fcntl.LOCK_EX)
                if not made.exists():
                    made.write_text(json.dumps(generate(replace(PRESETS[preset], **changes), str(out),
                                                        progress=False)._asdict()))
            cache[key] = GeneratedScenario(**json.loads(made.read_text()))
        return cache[key]

    return make


@pytest.fixture(scope="session")
def generated_cfg(tmp_path_factory):
    """cfg/AbsOrient.cfg through dynamic_reconfigure's own generator; the generated Python module."""
    root = Path(__file__).resolve().parents[1]
    out = tmp_path_factory.mktemp("cfg")
    proc = subprocess.run([sys.executable, str(root / "cfg" / "AbsOrient.cfg"), "/usr/share/dynamic_reconfigure",
                           str(out / "bin"), str(out / "cpp"), str(out / "py")], cwd=str(out),
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout
    spec = importlib.util.spec_from_file_location("AbsOrientConfig", str(out / "py" / "cfg" / "AbsOrientConfig.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# --------------------------------------------------------------------------- four workers (tools/test.sh: -n 4)
ROOT = Path(__file__).resolve().parents[1]
#: groups handed out first, one worker each: the rostests in two lanes side by side (each lane one rostest
#: after another; each rostest has its own roscore on a free port), and the Python 3.8 run of the core unit
#: tests in two parts (test_noetic.py's CORE_PARTS; its quick tests go with the first). A unit test file with
#: a module or class fixture (computed once) is a group; the other unit tests go one by one to the worker
#: that is free (a lane that has finished takes unit tests).
FIRST_GROUPS = ("rostests-1", "rostests-2", "noetic-1", "noetic-2")
#: about how long each rostest takes (s, this 2-core machine at load 8): the lanes are balanced by it (a
#: rostest not listed counts 30 s)
ROSTEST_SECONDS = {"abs_orient_consumer_bad.test": 76, "abs_orient_node.test": 70, "abs_orient_consumer.test": 67,
                   "abs_orient_loop.test": 52, "abs_orient_markers_only.test": 48, "abs_orient_consumer_ekf.test": 48,
                   "abs_orient_chaos.test": 43, "abs_orient_calibration.test": 41, "abs_orient_ekf.test": 35,
                   "ms60_chaos.test": 31, "abs_orient_bad_inputs.test": 26, "ms60.test": 22, "synthetic_bag.test": 18,
                   "abs_orient_startup.test": 22, "abs_orient_raw.test": 7}


def rostest_lanes(names):
    """{rostest file name: 'rostests-1' or 'rostests-2'}: the longest first, each to the lane with less so far."""
    lanes, load = {}, {"rostests-1": 0.0, "rostests-2": 0.0}
    for name in sorted(names, key=lambda n: -ROSTEST_SECONDS.get(n, 30)):
        lane = min(load, key=load.get)
        lanes[name] = lane
        load[lane] += ROSTEST_SECONDS.get(name, 30)
    return lanes


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(session, config, items):
    if not config.pluginmanager.hasplugin("xdist"):  # .venv-noetic runs the core tests without it
        return
    lanes = rostest_lanes([item.callspec.params["name"] for item in items
                           if Path(str(item.fspath)).name == "test_rostests.py"])
    for item in items:
        path = Path(str(item.fspath))
        group = (lanes[item.callspec.params["name"]] if path.name == "test_rostests.py"
                 else _noetic_lane(item) if path.name == "test_noetic.py" else None)
        shared = getattr(item, "_fixtureinfo", None) and any(
            d[-1].scope in ("module", "class", "package") for d in item._fixtureinfo.name2fixturedefs.values())
        if group or shared:
            item.add_marker(pytest.mark.xdist_group(group or path.relative_to(ROOT).as_posix()))


def _noetic_lane(item) -> str:
    """'noetic-2' for the second part of the core tests' Python 3.8 run, 'noetic-1' for the rest of test_noetic.py."""
    part = getattr(item, "callspec", None) and item.callspec.params.get("part")
    return f"noetic-{(part or 0) + 1}"


try:
    from xdist.scheduler import LoadGroupScheduling
except ImportError:  # no pytest-xdist (.venv-noetic): one process runs everything in file order
    LoadGroupScheduling = None

if LoadGroupScheduling is not None:
    class _FirstGroupsFirst(LoadGroupScheduling):
        """pytest-xdist's --dist loadgroup, with the groups of FIRST_GROUPS handed out before the rest
        (loadgroup orders groups by their number of tests; these have few tests that take minutes)."""

        def _assign_work_unit(self, node):
            for group in reversed(FIRST_GROUPS):
                if group in self.workqueue:
                    self.workqueue.move_to_end(group, last=False)
            super()._assign_work_unit(node)

    @pytest.hookimpl(optionalhook=True)  # pytest-xdist installed but off (-p no:xdist)
    def pytest_xdist_make_scheduler(config, log):
        return _FirstGroupsFirst(config, log) if config.getvalue("dist") == "loadgroup" else None
