"""``-c`` may be left out: a command then reads ``$CANOPEN_GATEWAY_CONFIG``, else
``/etc/canopen-gateway/config.yaml``; without either it says both, in one line, exit 2."""

from __future__ import annotations

from pathlib import Path

import pytest

from canopen_gateway.cli import main
from canopen_gateway.cli.load import DEFAULT_CONFIG, default_config
from canopen_gateway.config import ConfigError

DEMO = str(Path(__file__).resolve().parents[2] / "config" / "demo.yaml")


def test_the_variable_names_the_config_of_a_command_without_c(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("CANOPEN_GATEWAY_CONFIG", DEMO)
    assert main(["registers", "--format", "modicon", "--unit", "1"]) == 0
    assert capsys.readouterr().out.startswith("unit_id,modicon,")
    assert main(["check"]) == 0
    assert capsys.readouterr().out.startswith(f"{DEMO}: OK")


def test_the_etc_file_is_next_and_without_either_the_error_says_both(tmp_path: Path) -> None:
    etc = tmp_path / "config.yaml"
    with pytest.raises(ConfigError) as exc:
        default_config({}, default=str(etc))
    (line,) = exc.value.problems
    assert "CANOPEN_GATEWAY_CONFIG" in line and str(etc) in line and "-c FILE" in line
    etc.write_text("can: {interface: virtual}\n")
    assert default_config({}, default=str(etc)) == str(etc)
    assert default_config({"CANOPEN_GATEWAY_CONFIG": DEMO}, default=str(etc)) == DEMO
    with pytest.raises(ConfigError) as exc:  # a missing file says the variable named it
        default_config({"CANOPEN_GATEWAY_CONFIG": "/x.yaml"}, default=str(etc))
    assert exc.value.problems == ["error: /x.yaml: file does not exist (named by CANOPEN_GATEWAY_CONFIG; or give -c FILE)"]
    assert DEFAULT_CONFIG == "/etc/canopen-gateway/config.yaml"


def test_a_command_without_c_nor_either_exits_2_naming_both(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv("CANOPEN_GATEWAY_CONFIG", raising=False)
    if Path(DEFAULT_CONFIG).exists():
        pytest.skip(f"{DEFAULT_CONFIG} exists on this machine")
    assert main(["keys"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "CANOPEN_GATEWAY_CONFIG" in err[0] and DEFAULT_CONFIG in err[0]
