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
    ``GeneratedScenario``."""
    import fcntl
    import hashlib
    import json
    from dataclasses import replace

    from aruco_abs_orient.synthetic.bag import GeneratedScenario, generate
    from aruco_abs_orient.synthetic.scenario import PRESETS

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):  # the workers' base temps share this parent
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


# --------------------------------------------------------------------------- two workers (tools/test.sh: -n 2)
ROOT = Path(__file__).resolve().parents[1]
#: groups handed out first, one worker each: the rostests, one after another, and the Python 3.8 run of the
#: core unit tests (test_noetic.py; mostly it waits on simulated instruments and clocks). A unit test file
#: with a module or class fixture (computed once) is a group; the other unit tests go one by one to the
#: worker that is free (tools/test.sh runs them after the first two).
FIRST_GROUPS = ("rostests", "noetic")


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(session, config, items):
    if not config.pluginmanager.hasplugin("xdist"):  # .venv-noetic runs the core tests without it
        return
    for item in items:
        path = Path(str(item.fspath))
        group = {"test_rostests.py": "rostests", "test_noetic.py": "noetic"}.get(path.name)
        shared = getattr(item, "_fixtureinfo", None) and any(
            d[-1].scope in ("module", "class", "package") for d in item._fixtureinfo.name2fixturedefs.values())
        if group or shared:
            item.add_marker(pytest.mark.xdist_group(group or path.relative_to(ROOT).as_posix()))


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
