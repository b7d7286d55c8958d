"""Shared pytest set-up: hypothesis profiles (no deadlines on a shared 2-core machine) and the
synthetic scenarios the pipeline tests share."""
import os

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile("default", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("ci", deadline=None, max_examples=50, suppress_health_check=[HealthCheck.too_slow])
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
