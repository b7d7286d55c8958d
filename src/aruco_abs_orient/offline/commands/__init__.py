"""The sub-commands of ``aruco-abs-orient``, one module each: ``add_parser(subparsers)`` and ``run(args)``.

In: the ``argparse`` sub-parsers of :func:`aruco_abs_orient.offline.cli.build_parser`. Out: each module's
``add_parser`` registers its sub-command (its options, help and examples) and sets ``run`` as the parsed
arguments' ``handler``; ``run(args)`` parses nothing more, calls the library (``offline.process``,
``offline.calibrate``, ``offline.sync``, ``offline.evaluate``, …), prints for people and returns the exit status
(an error of the package is raised, and printed by the one boundary, :func:`aruco_abs_orient.errors.run`).
:data:`COMMANDS` lists them in the order ``--help`` shows them; a new command is a module here and an entry
there.
"""

from . import calibrate, evaluate, map, markers, params, process, timesync, video_to_bag

COMMANDS = (process, timesync, evaluate, calibrate, map, params, markers, video_to_bag)
