"""``itskill`` (and ``python -m itskill``): the command-line app.

Importing the app loads the simulator and torch, which takes seconds: a Ctrl-C then ends the
command quietly, as one during a command does, instead of with an import traceback.
"""

from __future__ import annotations

import sys


def main() -> None:
    """Run the ``itskill`` command line."""
    try:
        from itskill.cli import app
    except KeyboardInterrupt:
        sys.stderr.write("interrupted\n")
        raise SystemExit(130) from None
    app()


if __name__ == "__main__":
    main()
