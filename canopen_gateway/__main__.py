"""``python -m canopen_gateway`` runs the command line.

Imports: entry.
"""

from canopen_gateway.entry import main

raise SystemExit(main())
