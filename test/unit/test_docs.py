"""The documentation against the code: it cannot drift silently.

- ``doc/ros_api.md`` names every node (one per ``scripts/*`` entry point), every private parameter each
  node reads (found by running the nodes' own parameter readers with a recording parameter source, and
  by parsing every ``get_param("~…")`` call), with the code's default; every dynamic_reconfigure entry of
  ``cfg/AbsOrient.cfg`` (through dynamic_reconfigure's real generator) with its default and range;
  every topic each node publishes or subscribes with its message type; every diagnostics key; every
  ``<arg>`` of every launch file with its default.
- Every console script of ``setup.py`` (and each of its sub-commands) has ``--help`` with an example.
- The command lines in the documents' code blocks are real: ``aruco-abs-orient…`` lines parse with the
  CLI's own parser, ``roslaunch``/``rosrun`` lines name existing launch files/nodes and their args/params,
  the ``rosbag record`` line records what the offline tools read.
- Every relative link in ``doc/*.md`` and ``README.md`` points at an existing file.

Needs tools/env.sh sourced (rospy, dynamic_reconfigure), as `make test`. A few seconds.
"""
import argparse
import ast
import importlib
import importlib.util
import json
import math
import os
import re
import shlex
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "doc"
ROS_API = DOC / "ros_api.md"
PACKAGE = "aruco_abs_orient"


# ---------------------------------------------------------------------------------------------- markdown
def sections(text: str, level: int) -> dict:
    """{heading text: body} for the headings of exactly ``level`` (#'s); a body runs to the next heading of
    that level or higher."""
    out, current, lines = {}, None, []
    for line in text.splitlines():
        m = re.match(r"^(#+)\s+(.*)$", line)
        if m and len(m.group(1)) <= level:
            if current is not None:
                out[current] = "\n".join(lines)
            current, lines = (m.group(2).strip() if len(m.group(1)) == level else None), []
        elif current is not None:
            lines.append(line)
    if current is not None:
        out[current] = "\n".join(lines)
    return out


def section(text: str, level: int, contains: str) -> str:
    """The body of the one heading of ``level`` that contains ``contains``."""
    found = [body for head, body in sections(text, level).items() if contains in head]
    assert len(found) == 1, f"expected one level-{level} heading containing {contains!r}, found {len(found)}"
    return found[0]


def table_rows(body: str) -> dict:
    """{first cell's code name (without ``~``): [cells]} for every Markdown table row of ``body``."""
    rows = {}
    for line in body.splitlines():
        if not line.startswith("|"):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        m = re.fullmatch(r"`~?([^`]+)`", cells[0])
        if m:
            rows[m.group(1)] = cells
    return rows


_ANY = object()       # a default the code computes: only the row is checked
_REQUIRED = object()  # a launch arg without a default


def default_matches(cell: str, default) -> bool:
    """Does a table cell state ``default``? Numbers within 0.5 % (rounded in the text), booleans as
    true/false, tuples as YAML lists, strings in backticks, an empty string as 'required' or 'empty', None as
    'unset'."""
    text = cell.lower()
    if default is _REQUIRED:
        return "required" in text
    if default is None:
        return "unset" in text
    if isinstance(default, bool):
        return re.search(rf"\b{str(default).lower()}\b", text) is not None
    if isinstance(default, (int, float)):
        m = re.search(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", text)
        return m is not None and math.isclose(float(m.group(0)), float(default), rel_tol=5e-3, abs_tol=1e-12)
    if isinstance(default, tuple):  # numbers, as the YAML list [a, b, ...]
        m = re.findall(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", text)
        return len(m) == len(default) and all(math.isclose(float(x), float(d), rel_tol=5e-3)
                                              for x, d in zip(m, default))
    if default == "":
        return "required" in text or "empty" in text
    return f"`{default}`".lower() in text


def check_rows(body: str, expected: dict, what: str) -> list:
    """Problems: names of ``expected`` ({name: default}) without a table row, or with another default
    (second column)."""
    rows = table_rows(body)
    problems = []
    for name, default in sorted(expected.items()):
        if name not in rows:
            problems.append(f"{what}: `{name}` has no table row")
        elif default is not _ANY and not default_matches(rows[name][1], default):
            problems.append(f"{what}: `{name}`: the code's default is {default!r}, the document says {rows[name][1]!r}")
    return problems



# ---------------------------------------------------------------------------------------------- the code
def node_modules() -> dict:
    """{node type (scripts/ file name): module name} from the scripts' ``from … import main`` line."""
    out = {}
    for script in sorted((ROOT / "scripts").iterdir()):
        m = re.search(r"^from (aruco_abs_orient\.[\w.]+) import main$", script.read_text(), re.M)
        if m:
            out[script.name] = m.group(1)
    return out


def module_path(module: str) -> Path:
    return ROOT / "src" / Path(*module.split(".")).with_suffix(".py")


class RecordingParams(dict):
    """A stand-in for ``rospy.get_param("~")`` (a dict) that records every key read, nested dicts as
    ``parent/key``; an optional value (default None) reads as 1.0 so every branch is taken."""

    def __init__(self, prefix: str = "", seen: dict = None):
        super().__init__()
        self.prefix = prefix
        self.seen = {} if seen is None else seen

    def get(self, key, default=None):
        if isinstance(default, dict):
            return RecordingParams(f"{self.prefix}{key}/", self.seen)
        self.seen[self.prefix + key] = default
        return 1.0 if default is None else default


def literal_get_params(module: str) -> dict:
    """{name: default or _ANY} of every ``get_param("~name"[, default])`` call with a literal name."""
    out = {}
    for node in ast.walk(ast.parse(module_path(module).read_text())):
        if not (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) == "get_param"
                and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            continue
        name = node.args[0].value
        if name.startswith("~") and len(name) > 1:
            default = node.args[1] if len(node.args) > 1 else None
            out[name[1:]] = default.value if isinstance(default, ast.Constant) else _ANY
    return out


def node_params() -> dict:
    """{node: {param: default}} of every node, from its parameter reader and its literal get_param calls."""
    from aruco_abs_orient.nodeconfig import NodeConfig, NodeConfigError
    from aruco_abs_orient.ros.ms60_node import config_from_params

    out = {node: literal_get_params(mod) for node, mod in node_modules().items()}
    seen = {}

    def get_param(name, default):
        seen[name.lstrip("~")] = default
        return default

    with pytest.raises(NodeConfigError):  # ~markers has no default: everything else was read before
        NodeConfig.from_params(get_param)
    out["abs_orient"].update(seen)
    recorder = RecordingParams()
    config_from_params(recorder)
    out["ms60_driver"].update(recorder.seen)
    return out


def publishers_and_subscribers(module: str) -> dict:
    """{topic: message type name} of every ``Publisher``/``Subscriber`` created with a literal topic."""
    out = {}
    for node in ast.walk(ast.parse(module_path(module).read_text())):
        if (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None))
                in ("Publisher", "Subscriber") and len(node.args) >= 2 and isinstance(node.args[0], ast.Constant)):
            kind = node.args[1]
            out[node.args[0].value] = kind.id if isinstance(kind, ast.Name) else kind.attr
    return out


def abs_orient_diagnostic_keys() -> set:
    """The literal keys of the ``values`` dictionary of the abs_orient node's ``pipeline`` status
    (``nodestate.NodeHealth.report``), and those the node adds with ``….extra_values["key"] = …``."""
    keys = set()
    for module in ("aruco_abs_orient.nodestate", "aruco_abs_orient.ros.abs_orient_node"):
        for node in ast.walk(ast.parse(module_path(module).read_text())):
            target = getattr(node, "target", None) or (node.targets[0] if isinstance(node, ast.Assign) else None)
            value = getattr(node, "value", None)
            if isinstance(target, ast.Name) and target.id == "values" and isinstance(value, ast.Dict):
                keys |= {k.value for k in value.keys if isinstance(k, ast.Constant)}
            if (isinstance(target, ast.Subscript) and isinstance(target.slice, ast.Constant)
                    and (getattr(target.value, "id", None) == "values"
                         or getattr(target.value, "attr", None) == "extra_values")):
                keys.add(target.slice.value)
    return keys


def ms60_status_keys() -> set:
    """The keys of ms60/status (and of the driver's diagnostics), from the driver's own serialiser."""
    from aruco_abs_orient.geocom.tracker import TrackerStats
    from aruco_abs_orient.ros.ms60_node import stats_to_json

    values = {f: ({} if f in ("warnings", "no_position") else "" if f in ("state", "instrument") else 0.0)
              for f in TrackerStats._fields}
    return set(json.loads(stats_to_json(TrackerStats(**values))))


def launch_args() -> dict:
    """{launch file name: {arg: default, None when required}} of the top-level ``<arg>``s (those inside an
    ``<include>`` pass values on; they are not the file's own)."""
    out = {}
    for path in sorted((ROOT / "launch").glob("*.launch")):
        out[path.name] = {a.get("name"): a.get("default") for a in ET.parse(path).getroot().findall("arg")
                          if a.get("value") is None}
    return out


@pytest.fixture(scope="module")
def api() -> str:
    return ROS_API.read_text()


# ---------------------------------------------------------------------------------------------- ros_api.md
def test_extractors_find_the_known_parameters():
    """The extraction itself works (so the checks below are not vacuous)."""
    params = node_params()
    assert {"abs_orient", "ms60_driver", "static_tfs", "tf_to_odometry"} <= set(params)
    assert {"markers", "publish_tf", "time_offset", "tf_rate", "map_frame"} <= set(params["abs_orient"])
    assert params["abs_orient"]["tf_rate"] == 20.0
    assert {"port", "baud", "rate", "station/x", "station/instrument_height", "station/orientation_deg",
            "prism_constant_mm"} <= set(params["ms60_driver"])
    assert params["ms60_driver"]["baud"] == 115200
    assert {"calibration", "base_frame"} <= set(params["static_tfs"])
    assert params["tf_to_odometry"]["position_sigma"] == 0.005
    assert {"initialised", "time offset [s]", "prism age [s]", "map->odom yaw [deg]"} <= abs_orient_diagnostic_keys()
    assert {"state", "rate_hz", "clock_drift_ppm"} <= ms60_status_keys()
    assert publishers_and_subscribers("aruco_abs_orient.ros.abs_orient_node")["abs_orient/orientation"] == \
        "PoseWithCovarianceStamped"
    assert launch_args()["abs_orient.launch"]["markers"] is None


def test_every_node_parameter_is_documented_with_its_default(api):
    problems = []
    for node, params in sorted(node_params().items()):
        body = section(api, 2, f"`{node}`")
        problems += check_rows(section(body, 3, "Parameters"), params, f"node {node} parameters")
    assert not problems, "doc/ros_api.md is out of date:\n" + "\n".join(problems)


def test_every_dynamic_reconfigure_entry_is_documented_with_default_and_range(api, generated_cfg):
    body = section(section(api, 2, "`abs_orient`"), 3, "dynamic_reconfigure")
    problems = check_rows(body, dict(generated_cfg.defaults), "dynamic_reconfigure")
    rows = table_rows(body)
    for name in generated_cfg.defaults:
        if name in rows and generated_cfg.type[name] != "bool":
            lo, hi = (default_matches(rows[name][2], generated_cfg.min[name]),
                      default_matches(rows[name][3], generated_cfg.max[name]))
            if not (lo and hi):
                cfg_range = f"{generated_cfg.min[name]}..{generated_cfg.max[name]}"
                problems.append(f"dynamic_reconfigure: `{name}`: range {cfg_range} "
                                f"in the cfg, the document says {rows[name][2]}..{rows[name][3]}")
    assert not problems, "doc/ros_api.md is out of date:\n" + "\n".join(problems)


def test_the_pipeline_tunables_without_a_cfg_entry_are_listed(api, generated_cfg):
    """Tunables the pipeline has but the node cannot change (documented as fixed at their defaults)."""
    from aruco_abs_orient.pipeline import all_param_fields

    fixed = {name: default for _, name, default in all_param_fields() if name not in generated_cfg.defaults}
    body = section(section(api, 2, "`abs_orient`"), 3, "Fixed tunables")
    problems = check_rows(body, fixed, "fixed tunables")
    rows = table_rows(body)
    problems += [f"fixed tunables: `{name}` is in cfg/params.yaml's section {group}, the document says {rows[name][2]}"
                 for group, name, _ in all_param_fields() if name in rows and rows[name][2] != group]
    assert not problems, "doc/ros_api.md is out of date:\n" + "\n".join(problems)


def test_every_topic_is_documented_with_its_type(api):
    problems = []
    for node, module in sorted(node_modules().items()):
        body = section(api, 2, f"`{node}`")
        topics = section(body, 3, "Topics")
        rows = table_rows(topics)
        for topic, kind in sorted(publishers_and_subscribers(module).items()):
            row = rows.get(topic.lstrip("~"))  # a private topic's row is `~name` (table_rows drops the ~)
            if row is None:
                problems.append(f"node {node}: topic `{topic}` has no row under Topics")
            elif not re.search(rf"\b{re.escape(kind)}\b", " ".join(row)):
                problems.append(f"node {node}: topic `{topic}`: the code uses {kind}, the row says {row}")
    assert not problems, "doc/ros_api.md is out of date:\n" + "\n".join(problems)


def test_every_diagnostics_key_is_documented(api):
    problems = []
    for node, keys in (("abs_orient", abs_orient_diagnostic_keys()), ("ms60_driver", ms60_status_keys())):
        rows = table_rows(section(section(api, 2, f"`{node}`"), 3, "Diagnostics"))
        problems += [f"node {node}: diagnostics key `{k}` has no row" for k in sorted(keys - set(rows))]
    assert not problems, "doc/ros_api.md is out of date:\n" + "\n".join(problems)


def test_every_launch_argument_is_documented_with_its_default(api):
    problems = []
    launch = section(api, 2, "Launch files")
    for name, args in sorted(launch_args().items()):
        body = section(launch, 3, f"`launch/{name}`")
        problems += check_rows(body, {a: _REQUIRED if d is None else d for a, d in args.items()}, f"launch/{name}")
    assert not problems, "doc/ros_api.md is out of date:\n" + "\n".join(problems)


def test_every_message_field_is_documented(api):
    fields = set()
    for line in (ROOT / "msg" / "MarkerObservation.msg").read_text().splitlines():
        words = line.split("#")[0].split()
        if len(words) == 2:
            fields.add(words[1])
    assert {"id", "azimuth", "yaw_sigma", "method"} <= fields
    documented = set(table_rows(section(api, 2, "Messages")))
    assert not fields - documented, f"doc/ros_api.md: MarkerObservation fields missing: {sorted(fields - documented)}"


def test_a_missing_parameter_is_caught():
    """The check fails on a document that lacks one parameter or states a wrong default."""
    body = "| name | default |\n|---|---|\n| `~tf_rate` | 20.0 Hz |\n| `~publish_tf` | `true` |\n"
    assert check_rows(body, {"tf_rate": 20.0, "publish_tf": True}, "x") == []
    assert len(check_rows(body, {"tf_rate": 20.0, "publish_tf": True, "tf_timeout": 0.05}, "x")) == 1
    assert len(check_rows(body, {"tf_rate": 30.0}, "x")) == 1
    assert len(check_rows(body, {"publish_tf": False}, "x")) == 1


# ---------------------------------------------------------------------------------------------- CLIs
def console_scripts() -> dict:
    """{command: module} from setup.py's console_scripts."""
    return dict(re.findall(r'"([\w-]+) = ([\w.]+):main"', (ROOT / "setup.py").read_text()))


class _Parser(Exception):
    pass


def cli_parser(module: str) -> argparse.ArgumentParser:
    """The ArgumentParser a CLI's main() builds (caught at its parse_args, before anything runs)."""
    real = argparse.ArgumentParser.parse_args

    def capture(self, *args, **kwargs):
        raise _Parser(self)

    argparse.ArgumentParser.parse_args = capture
    try:
        importlib.import_module(module).main([])
    except _Parser as e:
        return e.args[0]
    finally:
        argparse.ArgumentParser.parse_args = real
    raise AssertionError(f"{module}.main() never parsed its arguments")


def sub_parsers(parser: argparse.ArgumentParser) -> dict:
    return {name: p for action in parser._actions if isinstance(action, argparse._SubParsersAction)
            for name, p in action.choices.items()}


@pytest.mark.parametrize("command", sorted(console_scripts()))
def test_cli_help_runs_and_shows_an_example(command):
    module = console_scripts()[command]
    if importlib.util.find_spec(module) is None:
        pytest.fail(f"setup.py declares {command} = {module}:main but {module} does not exist")
    code = f"import sys; sys.argv = [{command!r}, '--help']; from {module} import main; sys.exit(main())"
    proc = subprocess.run([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    assert proc.returncode == 0, proc.stdout
    assert "example" in proc.stdout.lower(), f"{command} --help shows no example:\n{proc.stdout}"
    assert "``" not in proc.stdout, f"{command} --help shows reStructuredText markup:\n{proc.stdout}"
    for name, sub in sub_parsers(cli_parser(module)).items():
        text = sub.format_help()
        assert "example" in text.lower(), f"{command} {name} --help shows no example"
        assert sub.description, f"{command} {name} --help has no description"
        assert "DESIGN" not in text, f"{command} {name} --help cites a document that is not in the repository"
        lines = text.splitlines()  # an example continued with a backslash goes on, indented, on the next line
        assert all(lines[i + 1].startswith("      ") for i, line in enumerate(lines[:-1]) if line.endswith("\\")), text


def test_every_command_is_in_the_tools_table(api):
    rows = table_rows(section(api, 2, "Command-line tools"))
    expected = set()
    for command, module in console_scripts().items():
        subs = sub_parsers(cli_parser(module))
        expected |= {f"{command} {name}" for name in subs} if subs else {command}
    assert "aruco-abs-orient process" in expected
    assert not expected - set(rows), f"doc/ros_api.md: commands missing: {sorted(expected - set(rows))}"


# ---------------------------------------------------------------------------------------------- doc examples
def documents() -> list:
    return sorted(DOC.glob("*.md")) + [ROOT / "README.md"]


def code_lines(path: Path, languages=None) -> list:
    """Command lines of the fenced code blocks (continuations joined, comments and prompts removed); with
    ``languages``, of the blocks whose fence names one of them only (e.g. ```bash)."""
    out, lang, pending = [], None, ""
    for line in path.read_text().splitlines():
        if line.lstrip().startswith("```"):
            lang, pending = (None if lang is not None else (line.strip()[3:].strip() or "plain")), ""
            continue
        if lang is None or (languages is not None and lang not in languages):
            continue
        line = re.sub(r"\s#\s.*$", "", line).strip()
        line = pending + line
        if line.endswith("\\"):
            pending = line[:-1] + " "
            continue
        pending = ""
        if line:
            out.append(line[2:] if line.startswith("$ ") else line)
    return out


def all_code_lines() -> list:
    return [(p.name, line) for p in documents() for line in code_lines(p)]


def test_documented_cli_command_lines_parse():
    scripts = console_scripts()
    checked = 0
    for doc, line in all_code_lines():
        words = shlex.split(line)
        if not words or words[0] not in scripts or "--help" in words:
            continue
        parser = cli_parser(scripts[words[0]])
        try:
            parser.parse_args(words[1:])
        except SystemExit:
            pytest.fail(f"{doc}: `{line}` does not parse with {words[0]}'s own parser")
        checked += 1
    assert checked >= 5, "the documents show fewer CLI examples than expected"


def test_documented_roslaunch_and_rosrun_lines_are_real():
    args, params = launch_args(), node_params()
    checked = 0
    for doc, line in all_code_lines():
        words = shlex.split(line)
        if len(words) < 3 or words[0] not in ("roslaunch", "rosrun") or words[1] != PACKAGE:
            continue
        settings = [w.split(":=", 1)[0] for w in words[3:] if ":=" in w]
        if words[0] == "roslaunch":
            assert words[2] in args, f"{doc}: `{line}`: no launch/{words[2]}"
            unknown = [s for s in settings if s not in args[words[2]]]
            assert not unknown, f"{doc}: `{line}`: launch/{words[2]} has no arg {unknown}"
        else:
            assert words[2] in params, f"{doc}: `{line}`: no node {words[2]} in scripts/"
            unknown = [s for s in settings if s.startswith("_") and s[1:] not in params[words[2]]]
            assert not unknown, f"{doc}: `{line}`: node {words[2]} reads no parameter {unknown}"
        checked += 1
    assert checked >= 3, "the documents show fewer roslaunch/rosrun examples than expected"


def test_the_rosbag_record_line_records_what_the_tools_read():
    from aruco_abs_orient.offline.bagio import BagTopics

    lines = [line for doc, line in all_code_lines() if doc == "field_guide.md" and line.startswith("rosbag record")]
    assert lines, "doc/field_guide.md has no `rosbag record` line"
    t = BagTopics()
    for line in lines:
        topics = set(shlex.split(line))
        missing = {t.image, t.tf, t.tf_static, t.prism} - topics
        assert not missing, f"field_guide.md: `{line}` does not record {sorted(missing)}"


def test_documented_make_targets_exist():
    targets = set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.M))
    for doc, line in all_code_lines():
        words = line.split()
        if words[:1] == ["make"]:
            assert {w for w in words[1:] if "=" not in w} <= targets, f"{doc}: `{line}`: no such make target"


# ---------------------------------------------------------------------------------------------- links
def anchors(path: Path) -> set:
    """GitHub's heading anchors of a Markdown file: lower case, punctuation dropped, spaces → '-',
    repeats numbered -1, -2, ..."""
    seen, out = {}, set()
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    for heading in re.findall(r"^#+\s+(.*?)\s*$", text, re.M):
        slug = re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def test_relative_links_point_at_existing_files_and_headings():
    broken = []
    for path in documents():
        text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)", text):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target):
                continue
            file_part, _, fragment = target.partition("#")
            resolved = (path.parent / file_part).resolve() if file_part else path
            if not resolved.exists():
                broken.append(f"{path.relative_to(ROOT)}: {target}")
            elif fragment and resolved.suffix == ".md" and fragment not in anchors(resolved):
                broken.append(f"{path.relative_to(ROOT)}: {target} (no such heading)")
    assert not broken, "broken relative links:\n" + "\n".join(broken)


def test_anchor_slugs_follow_github():
    doc = DOC / "robot_localization.md"
    assert {"a-no-ekf-the-node-owns-map--odom", "b-one-ekf-in-map-mode-launchekflaunch", "time"} <= anchors(doc)
    assert {"node-abs_orient", "diagnostics", "diagnostics-1", "dynamic_reconfigure"} <= anchors(ROS_API)


# ---------------------------------------------------------------------------------------------- messages
def message_templates() -> list:
    """Every string the package can print: its Python string literals (f-strings with each replacement
    field as NUL, implicit concatenations joined) and the text of tools/*.sh."""
    out = []
    for path in sorted((ROOT / "src" / PACKAGE).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.JoinedStr):
                out.append("".join(v.value if isinstance(v, ast.Constant) else "\0" for v in node.values))
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                out.append(node.value)
    out += [p.read_text() for p in sorted((ROOT / "tools").glob("*.sh"))]
    return out


def quoted_messages(path: Path) -> list:
    """The ``> ...`` lines of a document: messages the package prints, ``<...>`` for variable parts."""
    return [line.strip()[2:].strip() for line in path.read_text().splitlines() if line.strip().startswith("> ")]


def _in_one_template(message: str, templates: list) -> bool:
    parts = [re.escape(p) for p in re.split(r"<[^<>]*>", message)]
    pattern = re.compile("[^\n]*?".join(parts))
    return any(pattern.search(t) for t in templates)


def message_is_printed(message: str, templates: list) -> bool:
    """Some template holds the message's fixed parts in order (a variable part where it has ``<...>``), or
    the message is a prefix ending in ': ' plus an exception's text, each from one template."""
    if _in_one_template(message, templates):
        return True
    splits = [m.end() for m in re.finditer(": ", message)]
    return any(_in_one_template(message[:i] + "<text>", templates) and _in_one_template(message[i:], templates)
               for i in splits)


def test_quoted_messages_are_printed_by_the_code():
    templates = message_templates()
    messages = [(p.name, m) for p in documents() for m in quoted_messages(p)]
    assert len(messages) >= 15
    missing = [f"{doc}: {m}" for doc, m in messages if not message_is_printed(m, templates)]
    assert not missing, "the documents quote messages the code does not print:\n" + "\n".join(missing)
    assert not message_is_printed("no prism at all", templates)  # the check can fail
    assert not message_is_printed("no prism <x> at all", templates)
    assert not message_is_printed("aruco-abs-orient calibrate: error: <bag>: cannot frobnicate", templates)
