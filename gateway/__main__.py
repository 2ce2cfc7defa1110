"""``python -m gateway`` runs the command line."""

from gateway.entry import main

raise SystemExit(main())
