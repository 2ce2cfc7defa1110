"""The commands that hand the plant's own tools what they read: ``schema`` (the JSON Schema of
the configuration, or of a device profile, for an editor's YAML language server).

Imports: gateway.checks.json_schema.
"""

from __future__ import annotations

import argparse
import json
import sys


def cmd_schema(args: argparse.Namespace) -> int:
    from gateway.checks.json_schema import config_schema, profile_schema

    schema = profile_schema() if args.profile else config_schema()
    sys.stdout.write(json.dumps(schema, indent=2) + "\n")
    return 0
