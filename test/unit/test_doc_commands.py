"""Every command of the README and doc/*.md runs as written (issue 20), on the rendered ``ci`` scenario.

The ```bash blocks are taken in document order and played in a sandbox laid out as the documents
assume (``run1.bag`` = the ci scenario's bag, ``site/markers.yaml``, ``site/calibration.yaml`` with the
bag's lever arms, ``truth.tum``), with ``<placeholders>`` mapped to those files:

- ``aruco-abs-orient process`` and ``evaluate`` (without ``--fused``) and ``timesync`` without
  ``--markers`` are run, as written, in the sandbox: they must exit 0 (``timesync`` may answer with its
  documented refusal, exit status 1: the ci track turns at one rate); the others parse with the CLI's
  own parser (calibration and marker-bearing detection take minutes);
- every file a command reads must exist, or be written by a command before it (``--out``, ``record:=``);
- ``roslaunch`` lines are loaded by roslaunch's own loader from the sandbox (``$PWD``): the launch file,
  its args, the required ones, and every file parameter resolved to a file that exists;
- other commands name an executable that is installed (``rostopic``, ``rosbag``, ...), a file of the
  repository (``source tools/env.sh``) or a make target.
A command that does not run fails the build. About 40 s (the process run on the ci scenario).
"""
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from .test_docs import code_lines

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = sorted((ROOT / "doc").glob("*.md")) + [ROOT / "README.md"]
PLACEHOLDERS = {"<markers.yaml>": "site/markers.yaml", "<bag>": "run1.bag", "<reference.tum>": "truth.tum"}
RUN = {"process", "evaluate", "timesync"}


def bash_commands(path: Path) -> list:
    """The command lines of the ```bash blocks of ``path`` (continuations joined, comments removed)."""
    return code_lines(path, ("bash", "sh", "shell"))


def substitute(line: str) -> str:
    for key, value in PLACEHOLDERS.items():
        line = line.replace(key, value)
    left = re.findall(r"<[\w.\- ]+>", line)
    assert not left, f"`{line}`: placeholders without a file of the ci scenario: {left}"
    return line


@pytest.fixture(scope="module")
def sandbox(scenario_factory, tmp_path_factory):
    from aruco_abs_orient.offline.bagio import read_bag_data
    from aruco_abs_orient.transforms import matrix_to_rpy

    scen = scenario_factory("ci")
    box = tmp_path_factory.mktemp("doc_commands")
    (box / "site").mkdir()
    (box / "results").mkdir()
    os.symlink(scen.bag, box / "run1.bag")
    shutil.copy(scen.markers, box / "site" / "markers.yaml")
    shutil.copy(scen.truth, box / "truth.tum")
    data = read_bag_data(scen.bag)

    def entry(T):
        rpy = np.degrees(matrix_to_rpy(T[:3, :3]))
        xyz = ", ".join(f"{v:.6f}" for v in T[:3, 3])
        return f"{{xyz: [{xyz}], rpy_deg: [{', '.join(f'{v:.6f}' for v in rpy)}]}}"

    (box / "site" / "calibration.yaml").write_text(f"base_link_to_camera: {entry(data.base_T_camera)}\n"
                                                  f"base_link_to_prism: {entry(data.base_T_prism)}\n")
    return box


def _cli(words, cwd):
    code = ("import sys; from aruco_abs_orient.offline.cli import main; sys.argv[0] = 'aruco-abs-orient'; "
            "sys.exit(main(sys.argv[1:]))")
    path = f"{ROOT / 'src'}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"
    return subprocess.run([sys.executable, "-c", code, *words[1:]], cwd=str(cwd), stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, timeout=600, env={**os.environ, "PYTHONPATH": path})


def _inputs_and_outputs(args) -> tuple:
    """Files an aruco-abs-orient command reads and writes (paths as given)."""
    reads, writes = [], []
    if args.command in ("process", "timesync", "calibrate", "map"):
        reads += args.bag                       # one or several bags (a split recording)
    if args.command == "evaluate":
        reads.append(args.run)
        reads += [p for p in (args.reference, args.fused) if p]
        reads += list(args.overview or [])
    for name in ("markers", "calibration", "control", "compare"):
        if getattr(args, name, None):
            reads.append(getattr(args, name))
    for name in ("out", "plot"):
        if getattr(args, name, None):
            writes.append(getattr(args, name))
    return reads, writes


def _check_roslaunch(words, box, produced, where):
    import roslaunch.config
    import roslaunch.xmlloader

    launch = ROOT / "launch" / words[2]
    assert launch.exists(), f"{where}: no launch/{words[2]}"
    settings = [w for w in words[3:] if ":=" in w]
    config = roslaunch.config.ROSLaunchConfig()
    loader = roslaunch.xmlloader.XmlLoader()
    loader.ignore_unset_args = False
    old = os.environ.get("PWD")
    os.environ["PWD"] = str(box)  # as the shell in the sandbox sets it
    try:
        loader.load(str(launch), config, verbose=False, argv=["roslaunch", *settings])
    except Exception as e:
        pytest.fail(f"{where}: roslaunch cannot load it: {e}")
    finally:
        os.environ["PWD"] = old or ""
    for name, param in config.params.items():
        if name.rsplit("/", 1)[-1] in ("bag", "markers", "calibration") and param.value:
            assert os.path.isfile(param.value), f"{where}: {name} = {param.value} does not exist"
    for node in config.nodes:
        m = re.search(r"--output-name=(\S+)", node.args or "")
        if m:
            assert os.path.isdir(os.path.dirname(m.group(1))), f"{where}: record:= into a missing directory"
            produced.add(os.path.relpath(m.group(1), box))


def test_every_documented_command_runs_or_parses(sandbox):
    from aruco_abs_orient.offline.cli import build_parser

    box, produced, ran, checked = sandbox, set(), [], 0
    makefile_targets = set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.M))
    for doc in DOCUMENTS:
        for raw in bash_commands(doc):
            line = substitute(raw)
            where = f"{doc.name}: `{raw}`"
            words = shlex.split(line)
            checked += 1
            if words[0] == "aruco-abs-orient":
                try:
                    args = build_parser().parse_args(words[1:])
                except SystemExit:
                    pytest.fail(f"{where}: does not parse")
                reads, writes = _inputs_and_outputs(args)
                missing = [p for p in reads if not (box / p).exists() and os.path.normpath(p) not in produced]
                assert not missing, f"{where}: reads files that no earlier command writes: {missing}"
                unrun = [p for p in reads if not (box / p).exists()]
                if args.command in RUN and not unrun and not (args.command == "timesync" and args.markers):
                    proc = _cli(words, box)
                    # timesync may refuse a recording that does not determine the offset (exit status 1, its
                    # documented answer: the ci track turns at one rate); bad input (2) or a crash never passes
                    refused = args.command == "timesync" and proc.returncode == 1 and "no time offset:" in proc.stdout
                    assert proc.returncode == 0 or refused, \
                        f"{where}: exit status {proc.returncode}:\n{proc.stdout[-3000:]}"
                    ran.append(raw)
                produced.update(os.path.normpath(p) for p in writes)
            elif words[0] == "roslaunch":
                assert words[1] == "aruco_abs_orient", where
                _check_roslaunch(words, box, produced, where)
            elif words[0] == "make":
                assert set(words[1:]) <= makefile_targets, f"{where}: no such make target"
            elif words[0] == "source":
                assert (ROOT / words[1]).exists(), f"{where}: no {words[1]} in the repository"
            else:
                assert shutil.which(words[0]), f"{where}: {words[0]} is not installed here"
    assert checked >= 25 and len(ran) >= 4, (checked, ran)
    assert (box / "results" / "run1" / "report.md").exists()  # evaluate wrote its report where the guide says


def test_the_checks_can_fail(sandbox):
    """A command with a wrong option, a missing file or an unknown launch arg is caught."""
    from aruco_abs_orient.offline.cli import build_parser

    with pytest.raises(SystemExit):
        build_parser().parse_args(shlex.split("process run1.bag --out results/x"))  # no --markers
    with pytest.raises(AssertionError, match="placeholders"):
        substitute("aruco-abs-orient process <my bag> --markers m.yaml --out r")
    with pytest.raises(pytest.fail.Exception):
        _check_roslaunch(shlex.split("roslaunch aruco_abs_orient live.launch calibration:=x.yaml"), sandbox, set(),
                         "test")  # markers:= missing
    with pytest.raises(AssertionError, match="does not exist"):
        _check_roslaunch(shlex.split("roslaunch aruco_abs_orient postprocess.launch bag:=nope.bag "
                                     "markers:=site/markers.yaml"), sandbox, set(), "test")
