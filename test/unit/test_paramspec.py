"""paramspec.py: a parameter declared once (default, meaning, unit, range or choices) is checked on every object
made or replaced, read from YAML or ROS as its type, and its range is written the same way everywhere."""
import dataclasses
from dataclasses import dataclass
from typing import Optional, Tuple

import pytest

from aruco_abs_orient.errors import ConfigurationError
from aruco_abs_orient.paramspec import Params, coerce, describe_range, param, problem, short_range, spec_of, specs


class ToyError(ConfigurationError):
    pass


@dataclass
class Toy(Params):
    error = ToyError

    gate: float = param(4.0, "a gate", "σ", 0.0, 100.0)
    rate: float = param(1.0, "a rate", "Hz", above=0.0)
    share: float = param(0.5, "a share", "", 0.0, below=1.0)
    count: int = param(3, "a count", "", 1)
    reduce: int = param(1, "a reduction", "", choices=(1, 2, 4, 8))
    loss: str = param("cauchy", "a loss", choices=("cauchy", "none"))
    on: bool = param(True, "a switch")
    scales: Tuple[float, ...] = param((1.0, 0.5), "scales", "", above=0.0, high=1.0)
    limit: Optional[float] = param(2.0, "a limit (null: none)", "m", above=0.0, optional=True)

    def check_together(self) -> None:
        if self.count > 50 and self.on:
            raise ToyError("Toy.count/on: more than 50 only when off")


@pytest.mark.parametrize("name, ranged, short", [
    ("gate", "a number in [0, 100]", "[0, 100]"),
    ("rate", "a positive number", "> 0"),
    ("share", "a number in [0, 1)", "[0, 1)"),
    ("count", "an integer ≥ 1", "integer ≥ 1"),
    ("reduce", "one of 1, 2, 4 or 8", "1 | 2 | 4 | 8"),
    ("loss", "one of 'cauchy' or 'none'", "cauchy | none"),
    ("on", "true or false", "true | false"),
    ("scales", "a list of numbers each in (0, 1]", "each (0, 1]"),
    ("limit", "a positive number, or null (off)", "> 0 or null"),
])
def test_the_range_is_written_from_the_declaration(name, ranged, short):
    assert describe_range(spec_of(Toy, name)) == ranged
    assert short_range(spec_of(Toy, name)) == short


@pytest.mark.parametrize("changes, message", [
    ({"gate": 101.0}, "Toy.gate: expected a number in [0, 100], got 101.0"),
    ({"rate": 0.0}, "Toy.rate: expected a positive number, got 0.0"),
    ({"share": 1.0}, "Toy.share: expected a number in [0, 1), got 1.0"),
    ({"count": 2.0}, "Toy.count: expected an integer ≥ 1, got 2.0"),
    ({"reduce": 3}, "Toy.reduce: expected one of 1, 2, 4 or 8, got 3"),
    ({"reduce": 2.0}, "Toy.reduce: expected one of 1, 2, 4 or 8, got 2.0"),
    ({"loss": "l2"}, "Toy.loss: expected one of 'cauchy' or 'none', got 'l2'"),
    ({"on": 1}, "Toy.on: expected true or false, got 1"),
    ({"scales": ()}, "Toy.scales: expected a list of numbers each in (0, 1], got ()"),
    ({"gate": float("nan")}, "Toy.gate: expected a number in [0, 100], got nan"),
    ({"count": 60}, "Toy.count/on: more than 50 only when off"),
])
def test_every_field_is_checked_when_made_or_replaced(changes, message):
    with pytest.raises(ToyError) as e:
        Toy(**changes)
    assert str(e.value) == message
    with pytest.raises(ToyError):
        dataclasses.replace(Toy(), **changes)


def test_a_valid_object_and_its_declarations():
    assert Toy(limit=None, count=60, on=False).limit is None
    assert list(specs(Toy)) == [f.name for f in dataclasses.fields(Toy)]
    assert spec_of(Toy, "gate").unit == "σ" and spec_of(Toy, "gate").meaning == "a gate"
    assert problem(50.0, spec_of(Toy, "gate")) == ""


def test_coerce_reads_yaml_and_ros_values_as_the_declared_type():
    assert coerce(2, spec_of(Toy, "gate"), 4.0) == 2.0 and isinstance(coerce(2, spec_of(Toy, "gate"), 4.0), float)
    assert coerce([1, 0.5], spec_of(Toy, "scales"), (1.0,)) == (1.0, 0.5)
    assert coerce(None, spec_of(Toy, "limit"), 2.0) is None
    with pytest.raises(ValueError, match="expected a number, got None"):
        coerce(None, spec_of(Toy, "gate"), 4.0)
    with pytest.raises(ValueError, match="expected an integer, got 2.5"):
        coerce(2.5, spec_of(Toy, "count"), 3)
    with pytest.raises(ValueError, match="expected true or false, got 'yes'"):
        coerce("yes", spec_of(Toy, "on"), True)


def test_a_word_roslaunch_reads_as_a_boolean_is_the_choice_it_spells():
    """roslaunch's <param value="true"/> and YAML's true are booleans: ~north's choice 'true' must still be read."""
    from aruco_abs_orient.nodeconfig import NodeConfig

    north = spec_of(NodeConfig, "north")
    assert coerce(True, north, "grid") == "true" and coerce("grid", north, "grid") == "grid"
    with pytest.raises(ValueError, match="got False"):
        coerce(False, north, "grid")
    with pytest.raises(ValueError, match="got True"):
        coerce(True, spec_of(Toy, "loss"), "cauchy")
