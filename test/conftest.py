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
    """Generated synthetic scenarios (bag + truth), rendered once per session and shared:
    ``scenario_factory("ci", time_offset=0.2)`` → ``GeneratedScenario``."""
    from dataclasses import replace

    from aruco_abs_orient.synthetic.bag import generate
    from aruco_abs_orient.synthetic.scenario import PRESETS

    cache = {}

    def make(preset: str, **changes):
        key = (preset, tuple(sorted(changes.items())))
        if key not in cache:
            out = tmp_path_factory.mktemp(f"scenario_{preset}")
            cache[key] = generate(replace(PRESETS[preset], **changes), str(out), progress=False)
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


# --------------------------------------------------------------------------- test order and the Noetic run
NOETIC_CORE = "test_core_unit_tests_pass_on_noetics_versions"


def pytest_collection_modifyitems(session, config, items):
    """The rostests first (their timing on a machine nobody else loads), then the unit tests, test_noetic last:
    its Python 3.8 run of the core unit tests goes on in the background while the unit tests run (mostly it
    waits on simulated instruments and clocks), and the test collects it at the end."""
    def rank(item):
        name = Path(str(item.fspath)).name
        return 0 if name == "test_rostests.py" else 2 if name == "test_noetic.py" else 1
    items.sort(key=rank)  # stable: the order within each group is kept
    config._noetic_core = next((i for i in items if i.name == NOETIC_CORE), None)


def pytest_runtest_setup(item):
    core = getattr(item.config, "_noetic_core", None)
    if core is not None and "/test/unit/" in str(item.fspath) and not core.module.BACKGROUND.get("started"):
        core.module.BACKGROUND["started"] = True
        if core.module.NOETIC_PY.is_file():  # without it the test itself fails and says how to get one
            core.module.BACKGROUND["run"] = core.module.CoreRun()


def pytest_sessionfinish(session, exitstatus):
    core = getattr(session.config, "_noetic_core", None)
    run = core.module.BACKGROUND.pop("run", None) if core is not None else None
    if run is not None:  # started but never collected (the session was cut short)
        run.stop()
