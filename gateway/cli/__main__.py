"""``python -m gateway.cli``: the command line (``gateway.cli.main``).

Imports: gateway.cli.
"""

from gateway.cli import main

raise SystemExit(main())
