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
