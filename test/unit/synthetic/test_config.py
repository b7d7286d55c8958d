"""synthetic/config.py: a config's validation names the field, and its dict round trip (the hidden YAML's
``config``) gives the same config and refuses a malformed value."""
import dataclasses

import pytest

from aruco_abs_orient.synthetic.config import PRESETS, ScenarioConfig, ScenarioError

CFG = dataclasses.replace(PRESETS["ci"], duration=30.0)


@pytest.mark.parametrize("field,value", [
    ("fps", 0.0), ("width", 1001), ("duration", -1.0), ("seed", -1), ("profile", "fancy"),
    ("dictionary", "DICT_9X9"), ("marker_distance", (5.0, 2.0)), ("prism_dropout", 1.0),
])
def test_invalid_config_names_the_field(field, value):
    with pytest.raises(ScenarioError, match=field):
        dataclasses.replace(CFG, **{field: value}).validate()


def test_config_dict_round_trip():
    d = CFG.to_dict()
    assert ScenarioConfig.from_dict(d) == CFG
    with pytest.raises(ScenarioError, match="track_radii"):
        ScenarioConfig.from_dict(dict(d, track_radii=[1.0]))
