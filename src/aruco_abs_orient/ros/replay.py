"""Replay of a recording for ``postprocess.launch`` (node ``replay``): plays the bag with its clock,
says in one line how it ended, ends the launch quietly, and leaves a master it did not start as it was.

- Runs ``rosbag play --clock`` on ``~bag`` (the launch file makes a relative ``bag:=`` absolute against the
  directory roslaunch was started in). A missing bag is one line naming the full path tried, exit status 1.
- Counts what the ``abs_orient`` node and the EKF publish (``abs_orient/pose``, ``abs_orient/orientation``,
  ``odometry/filtered``) and keeps the node's newest ``/diagnostics`` status.
- When the bag has played to its end it waits ``~settle`` s (wall clock) for the last frames, logs

      replay: run1.bag played to its end (20.0 s): abs_orient processed 240 of 300 images (60 dropped), ...

  with the reason from the node's diagnostics when there is no pose, and asks its roslaunch to shut down
  (SIGINT to the parent process, as Ctrl-C does): the normal end is this line, not a red
  ``REQUIRED process has died``.
- On shutdown (the end, Ctrl-C, a failure) it deletes ``/use_sim_time`` from a master that its roslaunch
  did not start (a ``roscore`` running before): later nodes on that master are back on the wall clock.

Private params: ``~bag`` (path, required), ``~rate`` (1.0), ``~delay`` (2.0 s wall), ``~loop`` (false),
``~start`` (s into the bag where playback starts, 0),
``~settle`` (2.0 s wall).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from typing import Dict, Mapping, Optional

__all__ = ["main", "summary_line", "parent_is_roslaunch", "process_parent"]


def process_parent(pid: int) -> Optional[int]:
    """The parent pid of ``pid`` from /proc (None when the process does not exist here)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            stat = f.read()
    except OSError:
        return None
    return int(stat.rsplit(")", 1)[1].split()[1])


def parent_is_roslaunch(ppid: int) -> bool:
    """Whether process ``ppid`` is a roslaunch (its command line names roslaunch)."""
    try:
        with open(f"/proc/{ppid}/cmdline", "rb") as f:
            return b"roslaunch" in f.read()
    except OSError:
        return False


def summary_line(bag: str, duration: Optional[float], counts: Mapping[str, int],
                 diagnostics: Optional[Mapping[str, object]]) -> str:
    """The one line that ends a replay. ``counts``: messages received on ``pose``, ``orientation``,
    ``filtered``; ``diagnostics``: the node's newest status (its key/values, and ``message`` as it was
    while the bag played), None when it never reported."""
    head = f"replay: {os.path.basename(bag)} played to its end" + (f" ({duration:.1f} s)" if duration else "")
    if diagnostics is None:
        return (f"{head}; abs_orient reported nothing on /diagnostics and published {counts.get('pose', 0)} poses "
                "(did it start? see its lines above)")
    received = diagnostics.get("images received", "?")
    processed = diagnostics.get("images processed", "?")
    dropped = diagnostics.get("images dropped", 0)
    parts = [f"abs_orient processed {processed} of {received} images"
             + (f" ({dropped} dropped while it was busy: a smaller rate:= gives it more time)"
                if dropped not in (0, "0", "?") else "")]
    parts.append(f"published {counts.get('pose', 0)} poses and {counts.get('orientation', 0)} marker yaws")
    if counts.get("filtered") is not None:
        parts.append(f"the EKF {counts['filtered']} odometry/filtered")
    line = f"{head}: " + ", ".join(parts)
    if not counts.get("pose", 0):
        reason = str(diagnostics.get("message") or "")
        last = str(diagnostics.get("last error", "-"))
        if last not in ("", "-") and last not in reason:
            reason = f"{reason}; last error: {last}" if reason else last
        line += f"; no pose because: {reason or 'the node gave no reason'}"
    return line


def _master_is_ours(master) -> bool:
    """Whether the ROS master was started by the same roslaunch as this node (it ends with it)."""
    try:
        pid = int(master.getPid())
    except Exception:  # a master elsewhere, or gone
        return False
    return process_parent(pid) == os.getppid()


def main(argv=None) -> int:
    """Node entry point; returns the exit status (1: no bag or rosbag play failed)."""
    import rosgraph
    import rospy

    from . import exit_without_master

    exit_without_master("replay", "postprocess.launch", argv)
    rospy.init_node("replay", argv=argv)
    bag = rospy.get_param("~bag", "")
    rate = float(rospy.get_param("~rate", 1.0))
    delay = float(rospy.get_param("~delay", 2.0))
    loop = bool(rospy.get_param("~loop", False))
    start = float(rospy.get_param("~start", 0.0))
    settle = float(rospy.get_param("~settle", 2.0))
    master = rosgraph.Master(rospy.get_name())
    ours = _master_is_ours(master)

    def restore_clock() -> None:
        if ours:
            return
        try:
            if master.hasParam("/use_sim_time"):
                master.deleteParam("/use_sim_time")
                print("replay: removed /use_sim_time from the master (it was running before this launch)",
                      flush=True)
        except Exception as e:  # the master went away first
            print(f"replay: could not remove /use_sim_time from the master: {e}", file=sys.stderr, flush=True)

    rospy.on_shutdown(restore_clock)
    if not bag or not os.path.isfile(bag):
        rospy.logfatal(f"replay: no bag file {bag or '(bag:= is empty)'} (a relative bag:= is resolved against "
                       f"the directory roslaunch was started in)")
        restore_clock()
        return 1

    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry

    lock = threading.Lock()
    counts: Dict[str, Optional[int]] = {"pose": 0, "orientation": 0, "filtered": None}
    diag: Dict[str, object] = {}

    def counter(key):
        def cb(_msg):
            with lock:
                counts[key] = (counts[key] or 0) + 1
        return cb

    def on_diagnostics(msg):
        for s in msg.status:
            if s.name == "abs_orient: pipeline":
                with lock:
                    diag.clear()
                    diag.update({kv.key: kv.value for kv in s.values})
                    diag["message"] = s.message

    subs = [rospy.Subscriber("abs_orient/pose", PoseStamped, counter("pose"), queue_size=100),
            rospy.Subscriber("abs_orient/orientation", PoseWithCovarianceStamped, counter("orientation"),
                             queue_size=100),
            rospy.Subscriber("odometry/filtered", Odometry, counter("filtered"), queue_size=100),
            rospy.Subscriber("/diagnostics", DiagnosticArray, on_diagnostics, queue_size=10)]
    cmd = (["rosbag", "play", "--clock", f"--rate={rate:g}", f"--delay={delay:g}", f"--start={start:g}", bag]
           + (["--loop"] if loop else []))
    player = subprocess.Popen(cmd)
    rospy.on_shutdown(lambda: player.poll() is None and player.send_signal(signal.SIGINT))
    while player.poll() is None and not rospy.is_shutdown():
        time.sleep(0.1)
    if rospy.is_shutdown():  # Ctrl-C: roslaunch ends everything
        player.wait()
        return 0
    if player.returncode != 0:
        rospy.logfatal(f"replay: rosbag play {bag} failed (exit status {player.returncode}; its message is above)")
        return 1
    with lock:  # the node's state while the bag played (after it, the node says "no image for ...")
        playing = str(diag.get("message", ""))
    time.sleep(settle)  # wall clock: the sim clock stopped with the bag
    with lock:
        final = dict(diag, message=playing or diag.get("message", "")) if diag else None
        line = summary_line(bag, _bag_duration(bag), dict(counts), final)
    for s in subs:
        s.unregister()
    rospy.loginfo(line)
    ppid = os.getppid()
    if parent_is_roslaunch(ppid):
        os.kill(ppid, signal.SIGINT)  # end the launch as Ctrl-C does: no red "REQUIRED process has died"
        rospy.spin()
    return 0


def _bag_duration(bag: str) -> Optional[float]:
    """Seconds of recording in ``bag`` (rosbag's index), None when it cannot be read."""
    try:
        import rosbag

        with rosbag.Bag(bag) as b:
            return b.get_end_time() - b.get_start_time()
    except Exception:
        return None


if __name__ == "__main__":
    sys.exit(main())
