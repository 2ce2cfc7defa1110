"""The repository carries the Apache License 2.0 its package metadata names, verbatim: the file
is byte for byte the text the Apache Software Foundation publishes
(https://www.apache.org/licenses/LICENSE-2.0.txt, MD5 3b83ef96387f14655fc854ddc3c6bd57, the
digest Debian's /usr/share/common-licenses/Apache-2.0 also has)."""

from __future__ import annotations

import hashlib
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
APACHE_2_0_MD5 = "3b83ef96387f14655fc854ddc3c6bd57"


def test_license_file_is_the_apache_2_0_text_verbatim() -> None:
    data = (ROOT / "LICENSE").read_bytes()
    assert hashlib.md5(data).hexdigest() == APACHE_2_0_MD5  # noqa: S324 - a digest of a text
    assert b"APPENDIX: How to apply the Apache License to your work." in data


def test_package_metadata_names_the_license_of_the_file() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert project["license"] == "Apache-2.0"
