"""What ``check`` says about the mistakes of a first configuration: the ``can:`` section checked
against the interface's python-can parameters (a typo names the nearest key), a missing driver
library, an empty file, a file that does not say which bus it runs on, and overrides from the
environment blamed on their variable rather than on the file."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from canopen_gateway.bus.can_backend import can_section_problems, driver_problem, interface_keys
from canopen_gateway.cli import main
from tests.helpers import unique_channel

REPO = Path(__file__).resolve().parents[2]
WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "gateway.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def check(path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str], str]:
    code = main(["check", "-c", str(path)])
    out, err = capsys.readouterr()
    return code, err.strip().splitlines(), out


def test_typos_in_can_are_errors_naming_the_nearest_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write(
        tmp_path,
        yaml.safe_dump(
            {"can": {"interface": "virtual", "chanel": "can0", "bitrat": 500000}, "nodes": [WIRE]}
        ),
    )
    code, lines, out = check(path, capsys)
    assert code == 2 and out == ""
    lines = sorted(lines, key=lambda line: "chanel" not in line)
    assert len(lines) == 2
    assert lines[0].startswith(
        f"{path}: can.chanel: unknown key for interface 'virtual' (did you mean 'channel'?"
    )
    assert lines[1].startswith(
        f"{path}: can.bitrat: unknown key for interface 'virtual' (did you mean 'bitrate'?"
    )


def test_can_keys_are_the_interface_bus_parameters() -> None:
    # documented parameters of the backend's bus class are accepted, per interface
    assert (
        can_section_problems(
            {"interface": "pcan", "channel": "PCAN_USBBUS1", "state": "ACTIVE", "device_id": 1}
        )
        == []
    )
    assert can_section_problems({"interface": "kvaser", "channel": 0, "accept_virtual": True}) == []
    assert (
        can_section_problems({"interface": "socketcan", "channel": "can0", "local_loopback": True})
        == []
    )
    assert (
        can_section_problems({"interface": "virtual", "channel": "x", "f_clock": 8000000, "brp": 1})
        == []
    )
    # ... and only on their own interface
    [(key, why)] = can_section_problems(
        {"interface": "socketcan", "channel": "can0", "device_id": 1}
    )
    assert key == "can.device_id" and "unknown key for interface 'socketcan'" in why
    keys = interface_keys("socketcan")
    assert keys is not None and {"receive_own_messages", "can_filters", "reopen_backoff_s"} <= keys


def test_missing_driver_library_is_named_at_check(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    problem = driver_problem("pcan")
    if problem is None:
        pytest.skip("PCAN-Basic is installed here")
    path = write(
        tmp_path,
        yaml.safe_dump({"can": {"interface": "pcan", "channel": "PCAN_USBBUS1"}, "nodes": [WIRE]}),
    )
    code, lines, _ = check(path, capsys)
    assert code == 2
    assert lines == [f"{path}: can.interface: {problem}"]
    assert "PCAN-Basic library is not installed" in lines[0]


def test_empty_file_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write(tmp_path, "# nothing yet\n")
    code, lines, out = check(path, capsys)
    assert code == 2 and out == ""
    assert lines == [
        f"{path}: the file is empty; a config needs at least can: and nodes: (see config/demo.yaml)"
    ]


@pytest.mark.parametrize("can", [None, {"channel": "can0"}])
def test_a_file_must_name_its_can_interface(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], can: dict | None
) -> None:
    raw: dict = {"nodes": [WIRE]}
    if can is not None:
        raw["can"] = can
    code, lines, _ = check(write(tmp_path, yaml.safe_dump(raw)), capsys)
    assert code == 2
    assert len(lines) == 1 and ": can.interface: required key is missing" in lines[0]
    assert "virtual for simulated devices in this process" in lines[0]


def test_written_virtual_interface_is_accepted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write(
        tmp_path,
        yaml.safe_dump(
            {"can": {"interface": "virtual", "channel": unique_channel()}, "nodes": [WIRE]}
        ),
    )
    code, lines, out = check(path, capsys)
    assert (code, lines) == (0, [])
    assert out.startswith(f"{path}: OK")


def test_demo_config_still_checks(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(REPO)
    code, lines, out = check(Path("config/demo.yaml"), capsys)
    assert (code, lines) == (0, [])


def test_environment_override_errors_name_the_variable(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(REPO)
    monkeypatch.setenv("CANOPEN_GATEWAY__MODBUS__PROT", "502")
    monkeypatch.setenv("CANOPEN_GATEWAY__ZENOH__MODE", "router")
    code, lines, _ = check(Path("config/demo.yaml"), capsys)
    assert code == 2
    assert sorted(lines) == [
        "CANOPEN_GATEWAY__MODBUS__PROT: modbus.prot: unknown key (typo?); did you mean 'port'?",
        "CANOPEN_GATEWAY__ZENOH__MODE: zenoh.mode: must be one of 'peer' or 'client'",
    ]


def test_environment_can_key_typo_names_the_variable(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(REPO)
    monkeypatch.setenv("CANOPEN_GATEWAY__CAN__BITRAT", "250000")
    code, lines, _ = check(Path("config/demo.yaml"), capsys)
    assert code == 2
    assert len(lines) == 1
    assert lines[0].startswith(
        "CANOPEN_GATEWAY__CAN__BITRAT: can.bitrat: unknown key for interface 'virtual' (did you mean 'bitrate'?"
    )


def test_unknown_key_in_the_file_names_the_nearest_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    raw = {
        "can": {"interface": "virtual", "channel": unique_channel()},
        "nodes": [{**WIRE, "signals": {"position": {"unt": "mm"}}}],
        "modbus": {"prot": 502},
    }
    path = write(tmp_path, yaml.safe_dump(raw))
    code, lines, _ = check(path, capsys)
    assert code == 2
    assert sorted(lines) == [
        f"{path}: modbus.prot: unknown key (typo?); did you mean 'port'?",
        f"{path}: nodes[0].signals.position.unt: unknown key (typo?); did you mean 'unit'?",
    ]


def test_check_of_the_demo_finds_no_warning_in_our_own_device_files(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The AP05's set points and control word are ro by SDO and written by RPDO only (AP05
    manual 5.7.2.34, 5.7.2.42): its profile says so, and ``check`` counts them apart."""
    assert main(["check", "-c", str(REPO / "config/demo.yaml")]) == 0
    lines = [ln.strip() for ln in capsys.readouterr().out.splitlines() if ".eds:" in ln]
    assert len(lines) == 5, lines
    assert all(": 0 warnings" in ln for ln in lines), lines
    ap05 = next(ln for ln in lines if ln.split(":")[0].endswith("ap05.eds"))
    assert ap05.endswith(
        "ap05.eds: 0 warnings; 6 RPDO entries ro by SDO and written by RPDO only, as profile "
        "ap05 says (rpdo_only_writable)"
    )


def test_a_value_of_the_wrong_kind_is_named_with_the_value(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write(tmp_path, yaml.safe_dump({"can": {"interface": "virtual"}, "modbus": {"port": "5030x"}, "nodes": [WIRE]}))  # fmt: skip
    code, err, _ = check(path, capsys)
    assert (code, err) == (2, [f"{path}: modbus.port: got '5030x', must be a whole number"])


def test_a_misspelt_device_file_names_the_near_ones_in_its_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "devices").mkdir()
    (tmp_path / "devices" / "io401.eds").write_bytes((REPO / "tests/data/eds/io401.eds").read_bytes())
    for wrong, said in (
        ("devices/io410.eds", "; did you mean io401.eds?"),
        ("devices/drive.eds", f" (in {tmp_path / 'devices'}: io401.eds)"),
        ("device/io401.eds", f" (nor does its folder {tmp_path / 'device'})"),
    ):
        path = write(tmp_path, yaml.safe_dump({"can": {"interface": "virtual"}, "nodes": [{"name": "io", "node_id": 5, "eds": wrong}]}))  # fmt: skip
        code, err, _ = check(path, capsys)
        assert (code, err) == (2, [f"{path}: nodes[0].eds: {tmp_path / wrong}: file does not exist{said}"])


def test_a_register_clash_names_the_keys_of_both(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    wire = {**WIRE, "signals": {"velocity": {"address": 100}}}
    path = write(tmp_path, yaml.safe_dump({"can": {"interface": "virtual"}, "nodes": [wire]}))
    code, err, _ = check(path, capsys)
    assert (code, err) == (2, [
        f"{path}: nodes[0].signals.velocity: input register 100 of unit 1 is used twice: "
        "wire.velocity (nodes[0].signals.velocity) and wire.position (nodes[0])"
    ])  # fmt: skip
