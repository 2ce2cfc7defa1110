"""The ``canopen-gateway`` program: the command line, with the ways a terminal ends it early.

Ctrl-C while Python still imports the gateway (the first few tenths of a second) and a reader
that stops reading (``canopen-gateway check -c FILE | head -1``) end the program quietly,
without a traceback: exit code 130 for Ctrl-C, 0 for the closed pipe. Everything else is
``canopen_gateway.cli``'s. Imports the standard library, then ``canopen_gateway.cli`` inside the guard.

Imports: the standard library, then cli inside the guard.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

EXIT_INTERRUPTED = 130  # 128 + SIGINT, what shells report for Ctrl-C


def main(argv: Sequence[str] | None = None) -> int:
    try:
        from canopen_gateway.cli import main as cli_main

        code = cli_main(argv)
        sys.stdout.flush()  # a closed pipe shows here, inside the guard
        return code
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # the reader went away: send what is still buffered nowhere, so that the flush at
        # interpreter exit does not fail a second time
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
