"""The ``fmcwlog`` command (``python -m fmcwlog`` too).

The command line's modules take 0.4-1 s to load; Ctrl-C in that time ends the command as it does
later (:func:`fmcwlog.cli.main`): one line and exit status 130, not a traceback from an import.
"""

import sys


def main() -> None:
    try:
        from .cli import main as cli_main
    except KeyboardInterrupt:
        sys.stderr.write("fmcwlog: aborted\n")
        sys.exit(130)
    cli_main()


if __name__ == "__main__":
    main()
