"""Every command of the README and doc/*.md as a user types it, on the rendered ``ci`` scenario.

The ```bash blocks are taken in document order and played in a fresh directory laid out as the documents
assume before their first command (``run1.bag`` = the ci scenario's bag, ``site/markers.yaml`` its marker
map, ``truth.tum`` its truth), with ``<placeholders>`` mapped to those files. What each command gets:

- README.md and doc/field_guide.md (the user's path through the package), **run as written**:
  every ``aruco-abs-orient`` command (timesync, calibrate, process, evaluate, …) and ``roslaunch
  aruco_abs_orient postprocess.launch`` (a real replay, on a master of its own at a free port). Each must
  work (exit 0; the replay's last line ``played to its end`` and no failure), or fail with exit status 1 or 2
  and one line that says what is wrong and what to do (``…: error: …``; never a traceback);
  ``aruco-abs-orient-ms60-sim --pty`` must print the pseudo-terminal it serves;
- the other documents' ``aruco-abs-orient`` lines parse with the CLI's own parser and read files that exist
  or an earlier command writes (the field guide runs the same commands);
- ``roslaunch`` lines that need the robot or the instrument (``live.launch``, ``ms60.launch``,
  ``abs_orient.launch``) are loaded by roslaunch's own loader from the directory (``$PWD``): the launch file,
  its args, the required ones, and every file parameter resolved to a file that exists;
- commands that need a running robot (``rostopic``, ``rosbag record``, ``rosparam``) name an installed
  executable, ``source`` a file of the repository, ``make`` a target of the Makefile.

The test lists every command with what was done and what came out (printed; in the failure message when
one fails). About 90 s on 2 cores (three calibrations, a timesync with the markers, a process and a 20 s
replay of the ci scenario).
"""
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from .test_docs import code_lines

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = sorted((ROOT / "doc").glob("*.md")) + [ROOT / "README.md"]
RUN_AS_WRITTEN = {"field_guide.md", "README.md"}
PLACEHOLDERS = {"<markers.yaml>": "site/markers.yaml", "<bag>": "run1.bag", "<reference.tum>": "truth.tum"}
ROBOT_LAUNCHES = {"live.launch", "ms60.launch", "abs_orient.launch"}  # need the robot or the instrument
ERROR_LINE = re.compile(r"^aruco-abs-orient( \w+)?: error: \S.*$")


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
    """A fresh directory with what the documents assume before their first command: the recording, the
    marker map, the reference trajectory."""
    scen = scenario_factory("ci")
    box = tmp_path_factory.mktemp("doc_commands")
    (box / "site").mkdir()
    os.symlink(scen.bag, box / "run1.bag")
    shutil.copy(scen.markers, box / "site" / "markers.yaml")
    shutil.copy(scen.truth, box / "truth.tum")
    return box


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env(box: Path) -> dict:
    """The user's shell in the sandbox (tools/env.sh sourced): $PWD there, a master of its own."""
    return {**os.environ, "PWD": str(box), "ROS_MASTER_URI": f"http://localhost:{_free_port()}",
            "ROS_HOME": str(box / ".ros"), "MPLBACKEND": "Agg"}


def _cli(words, box):
    """The command as written (``--quiet`` added where it has a progress bar), in the sandbox."""
    code = ("import sys; from aruco_abs_orient.offline.cli import main; sys.argv[0] = 'aruco-abs-orient'; "
            "sys.exit(main(sys.argv[1:]))")
    quiet = ["--quiet"] if words[1] in ("process", "timesync", "calibrate", "video-to-bag") else []
    return subprocess.run([sys.executable, "-c", code, *words[1:], *quiet], cwd=str(box), capture_output=True,
                          text=True, timeout=900, env=_env(box))


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


def _outcome(proc) -> tuple:
    """(works, what came out in one line) of a finished aruco-abs-orient command."""
    err = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    if proc.returncode == 0:
        out = [ln for ln in proc.stdout.splitlines() if ln.strip()]
        return True, (out[-1] if out else "exit 0")
    last = err[-1] if err else ""
    refused = proc.returncode in (1, 2) and "Traceback" not in proc.stderr and ERROR_LINE.match(last)
    return bool(refused), f"exit {proc.returncode}: {last or proc.stdout[-300:]}"


def _replay(words, box):
    """roslaunch as written, in the sandbox, on a master of its own; (works, its last line)."""
    proc = subprocess.run(words, cwd=str(box), env=_env(box), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True, timeout=600, start_new_session=True)
    bag = next(os.path.basename(w.split(":=", 1)[1]) for w in words if w.startswith("bag:="))
    ends = [ln for ln in proc.stdout.replace("\r", "\n").splitlines() if f"replay: {bag} " in ln]
    last = ends[-1].split("replay: ", 1)[1] if ends else proc.stdout[-300:]
    failed = "REQUIRED process" in proc.stdout or not ends or "played to its end" not in last
    return not failed, last


def _simulator(words, box):
    """aruco-abs-orient-ms60-sim --pty runs until stopped: it must say which pseudo-terminal it serves."""
    sim = subprocess.Popen(words, cwd=str(box), env=_env(box), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           text=True, start_new_session=True)
    try:
        deadline, first = time.monotonic() + 20, ""
        while time.monotonic() < deadline and not first:
            first = sim.stdout.readline().strip()
        return "/dev/pts/" in first, first
    finally:
        os.killpg(sim.pid, signal.SIGINT)
        sim.wait(60)  # 0.1 s alone; once over 10 s under make test's four lanes on two cores


def test_every_documented_command_runs_or_says_what_to_do(sandbox):
    from aruco_abs_orient.offline.cli import build_parser

    box, produced, listed = sandbox, set(), []
    makefile_targets = set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), re.M))
    for doc in DOCUMENTS:
        run = doc.name in RUN_AS_WRITTEN
        for raw in bash_commands(doc):
            line = substitute(raw)
            where = f"{doc.name}: `{raw}`"
            words = shlex.split(line)
            if words[0] == "aruco-abs-orient":
                try:
                    args = build_parser().parse_args(words[1:])
                except SystemExit:
                    pytest.fail(f"{where}: does not parse")
                reads, writes = _inputs_and_outputs(args)
                missing = [p for p in reads if not (box / p).exists() and os.path.normpath(p) not in produced]
                assert not missing, f"{where}: reads files that no earlier command writes: {missing}"
                if run:
                    works, said = _outcome(_cli(words, box))
                    listed.append((where, "ran", works, said))
                else:
                    listed.append((where, "parsed", True, ""))
                produced.update(os.path.normpath(p) for p in writes)
            elif words[0] == "roslaunch":
                assert words[1] == "aruco_abs_orient", where
                if run and words[2] == "postprocess.launch":
                    works, said = _replay(words, box)
                    listed.append((where, "ran", works, said))
                    m = [w.split(":=", 1)[1] for w in words if w.startswith("record:=")]
                    assert not m or (box / m[0]).exists(), f"{where}: recorded nothing to {m[0]}"
                else:
                    _check_roslaunch(words, box, produced, where)
                    listed.append((where, "loaded" + (" (needs the robot)" if words[2] in ROBOT_LAUNCHES else ""),
                                   True, ""))
            elif words[0] == "aruco-abs-orient-ms60-sim" and run:
                works, said = _simulator(words, box)
                listed.append((where, "ran", works, said))
            elif words[0] == "make":
                assert set(words[1:]) <= makefile_targets, f"{where}: no such make target"
                listed.append((where, "make target", True, ""))
            elif words[0] == "source":
                assert (ROOT / words[1]).exists(), f"{where}: no {words[1]} in the repository"
                listed.append((where, "file", True, ""))
            else:
                assert shutil.which(words[0]), f"{where}: {words[0]} is not installed here"
                listed.append((where, "installed (needs a running robot)", True, ""))
    table = "\n".join(f"{'ok ' if ok else 'BAD'} {how:34s} {where}" + (f"\n      -> {said[:300]}" if said else "")
                      for where, how, ok, said in listed)
    print(table)
    assert all(ok for _, _, ok, _ in listed), "documented commands that neither work nor say what to do:\n" + table
    ran = [w for w, how, _, _ in listed if how == "ran"]
    assert len(listed) >= 30 and len(ran) >= 10, table
    assert (box / "results" / "run1" / "report.md").exists()  # evaluate wrote its report where the guide says
    assert (box / "site" / "calibration.yaml").exists()       # calibrate wrote the file the later steps use


def test_the_checks_can_fail(sandbox):
    """A command with a wrong option, a missing file, an unknown launch arg, or an error that is not one line
    is caught."""
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
    crash = subprocess.CompletedProcess([], 1, "", "Traceback (most recent call last):\n  ...\nKeyError: 'x'\n")
    assert _outcome(crash)[0] is False
    refused = _outcome(_cli(shlex.split("aruco-abs-orient process nope.bag --markers site/markers.yaml --out r"),
                            sandbox))
    assert refused[0] and refused[1].startswith("exit 2: aruco-abs-orient: error: "), refused
