"""ms60_driver parameter validation (no ROS master needed) and the status JSON."""
import json
import math

import pytest

pytest.importorskip("rospy")
from aruco_abs_orient.geocom.tracker import TrackerError, TrackerStats  # noqa: E402
from aruco_abs_orient.ros.ms60_node import config_from_params, stats_to_json  # noqa: E402


def test_defaults_and_full_station():
    config, frame = config_from_params({})
    assert (config.url, config.baud, config.rate_hz, frame) == ("/dev/ttyUSB0", 115200, 20.0, "map")
    assert config.station is None and config.prism_constant_m is None
    config, _ = config_from_params({"port": "socket://127.0.0.1:5025", "prism_constant_mm": -34.4,
                                    "min_latency_ms": 2, "station": {"x": 1, "y": 2.5, "z": 3,
                                                                     "instrument_height": 1.6, "orientation_deg": 90}})
    assert config.station == (1.0, 2.5, 3.0, 1.6)
    assert config.prism_constant_m == pytest.approx(-0.0344)
    assert config.orientation_rad == pytest.approx(math.pi / 2) and config.min_latency_s == pytest.approx(0.002)


@pytest.mark.parametrize("params, name", [
    ({"port": ""}, "~port"), ({"port": 5}, "~port"), ({"baud": 115201}, "~baud"), ({"baud": "fast"}, "~baud"),
    ({"baud": 9600.5}, "~baud"), ({"rate": 0}, "~rate"), ({"rate": float("nan")}, "~rate"),
    ({"timeout": -1}, "~timeout"), ({"prism_constant_mm": 5000}, "~prism_constant_mm"),
    ({"frame_id": ""}, "~frame_id"), ({"station": {"x": 1}}, "~station"), ({"station": {"q": 1}}, "~station"),
    ({"station": 3}, "~station"), ({"station": {"x": 1, "y": 2, "z": "a"}}, "~station/z"),
    ({"min_latency_ms": -1}, "~min_latency_ms"), ({"rate": True}, "~rate"),
])
def test_bad_parameters_name_themselves(params, name):
    with pytest.raises(TrackerError, match=name.replace("~", "~?")):
        config_from_params(params)


def test_status_json():
    stats = TrackerStats("locked", 10, 2, 19.8, {1284: 1}, {1285: 3}, 1, 0, 0, 0, 1, 5, 1, 1.5, -40e-6, "MS60")
    d = json.loads(stats_to_json(stats))
    assert d["state"] == "locked" and d["warnings"] == {"1284": 1} and d["clock_drift_ppm"] == pytest.approx(-40.0)
