"""An EDS past the bounds of a device description is refused in one line before it costs
memory: too big a file (an 18 MB file of 60,000 objects with ``CompactSubObj=254``, which
would make 15 million sub-objects, is refused without reading it), too many objects or
sub-objects (counted as the file declares them, ``CompactSubObj`` included)."""

from __future__ import annotations

import resource
import subprocess
import sys
from pathlib import Path

import pytest

from canopen_gateway.eds import EdsError, load_eds
from canopen_gateway.eds.parse import MAX_EDS_BYTES, MAX_SUB_OBJECTS

ROOT = Path(__file__).resolve().parents[2]
HEAD = (
    "[FileInfo]\nFileName=x.eds\n[DeviceInfo]\nVendorName=x\nProductName=x\n"
    "[MandatoryObjects]\nSupportedObjects=0\n"
)


def array(index: int, entries: int = 254) -> str:
    return (f"[{index:04X}]\nParameterName=Array {index:04X}\nObjectType=0x8\nDataType=0x0007\n"
            f"AccessType=rw\nDefaultValue=0\nPDOMapping=0\nCompactSubObj={entries}\n")  # fmt: skip


def test_an_18_mb_eds_of_60000_compact_arrays_is_refused_at_once_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "huge.eds"
    with path.open("w") as f:
        f.write(HEAD)
        for i in range(60_000):
            f.write(array(0x1000 + i) + "; padding to the size of the file of the report" * 4 + "\n")
    assert path.stat().st_size > 18_000_000
    proc = subprocess.Popen([sys.executable, "-m", "canopen_gateway", "eds", "lint", str(path)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2, (out, err)
    (line,) = (out + err).strip().splitlines()
    assert line.startswith(f"{path}: ") and f"more than {MAX_EDS_BYTES}" in line
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024  # of any child so far
    assert peak_mb < 500


def test_too_many_sub_objects_are_refused_before_they_are_built(tmp_path: Path) -> None:
    path = tmp_path / "arrays.eds"
    n = MAX_SUB_OBJECTS // 255 + 1  # each CompactSubObj=254 array: 255 entries
    path.write_text(HEAD + "".join(array(0x2000 + i) for i in range(n)))
    assert path.stat().st_size < MAX_EDS_BYTES
    with pytest.raises(EdsError) as err:
        load_eds(path)
    (line,) = err.value.problems
    assert f"more than {MAX_SUB_OBJECTS}" in line and line.startswith(str(path))


def test_a_file_within_the_bounds_loads(tmp_path: Path) -> None:
    path = tmp_path / "arrays.eds"
    path.write_text(HEAD + "".join(array(0x2000 + i) for i in range(10)))
    eds = load_eds(path)
    assert len(eds.od[0x2000].subindices) == 255
