"""The ``fmcwlog`` command (``python -m fmcwlog`` too).

The command line's modules take 0.4-1 s to load; Ctrl-C in that time ends the command as it does
later (:func:`fmcwlog.cli.main`): one line and exit status 130, not a traceback from an import.

When the command is done, every object it made is frozen out of the garbage collector
(:func:`gc.freeze`): the interpreter's exit would otherwise walk them all, numpy's, scipy's,
gtsam's and pyarrow's modules among them, in collections that free nothing the exit does not
free anyway (0.1 s of CPU a ``process`` run). Objects are still finalised as their references
go, and the ``atexit`` handlers run, as in any exit.
"""

import gc
import sys


def main() -> None:
    try:
        from .cli import main as cli_main
    except KeyboardInterrupt:
        sys.stderr.write("fmcwlog: aborted\n")
        sys.exit(130)
    try:
        cli_main()
    finally:
        gc.freeze()


if __name__ == "__main__":
    main()
