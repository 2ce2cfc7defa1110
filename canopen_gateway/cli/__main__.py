"""``python -m canopen_gateway.cli``: the command line (``canopen_gateway.cli.main``).

Imports: canopen_gateway.cli.
"""

from canopen_gateway.cli import main

raise SystemExit(main())
