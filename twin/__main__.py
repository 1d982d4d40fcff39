"""``twin`` and ``python -m twin``: the command line (:mod:`twin.cli`), safe to interrupt from
the first instant.

:func:`twin.cli.main` turns SIGINT and SIGTERM into a clean stop once it runs; before that the
command line's modules are still being imported, and Python's own handler would print a
traceback. From the package's first line (:mod:`twin._starting`, installed when the process is
the command) a signal in that moment ends the command at once, with the one line and the exit
status of an interruption: nothing has been written yet.
"""

from __future__ import annotations

import signal
import sys

from twin._starting import while_starting


def main() -> int:
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, while_starting)
    from twin.cli import main as cli_main

    code = cli_main()
    for s in (signal.SIGINT, signal.SIGTERM):
        # the command has finished and said so: a signal now has nothing left to interrupt
        signal.signal(s, signal.SIG_IGN)
    return code


if __name__ == "__main__":
    sys.exit(main())
