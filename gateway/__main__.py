"""``python -m gateway`` runs the command line.

Imports: entry.
"""

from gateway.entry import main

raise SystemExit(main())
