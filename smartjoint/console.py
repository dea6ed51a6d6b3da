"""The ``smartjoint`` console script.

Importing the command line pulls in numpy, scipy and the stages, which takes seconds; a Ctrl-C
in that time ends with one line and exit code 130, like one during a command, instead of a
traceback. Nothing has been written before a command starts.
"""

from __future__ import annotations

import sys


def main() -> int:
    try:
        from smartjoint.cli import main as run_command
    except KeyboardInterrupt:
        print("smartjoint: interrupted (SIGINT) while starting", file=sys.stderr)
        return 130
    return run_command()
