"""Secrets in the configuration: the placeholder password of the examples is refused in one
line naming where it came from (the file, or the environment variable), also from a password
file; the web token may come from a file (``web.token_file``), checked as ``web.token`` is."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from canopen_gateway.cli import main

BASE = {
    "gateway": {"name": "line1"},
    "can": {"interface": "virtual", "channel": "secrets"},
    "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
}


def config(tmp_path: Path, **sections: object) -> Path:
    path = tmp_path / "gateway.yaml"
    path.write_text(yaml.safe_dump({**BASE, **sections}))
    return path


def test_the_placeholder_password_from_the_environment_is_refused_naming_the_variable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    path = config(tmp_path, zenoh={"mode": "client", "connect": ["tcp/127.0.0.1:7447"],
                                   "auth": {"user": "gateway-line1", "password": "s3cret-enough"}})  # fmt: skip
    monkeypatch.setenv("CANOPEN_GATEWAY__ZENOH__AUTH__PASSWORD", "change-me")
    assert main(["run", "-c", str(path)]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("CANOPEN_GATEWAY__ZENOH__AUTH__PASSWORD: zenoh.auth.password: ")
    assert "'change-me' is the placeholder of the examples" in line


def test_the_placeholder_password_in_a_password_file_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "zenoh.password").write_text("change-me\n")
    path = config(tmp_path, zenoh={"auth": {"user": "gateway-line1", "password_file": "zenoh.password"}})
    assert main(["check", "-c", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}: zenoh.auth.password_file: {tmp_path / 'zenoh.password'}: 'change-me'" in err


@pytest.mark.parametrize(
    ("content", "problem"),
    [(None, "cannot read"), ("short\n", "fewer than 12 characters"), ("a-long-enough-token\n", None)],
)
def test_the_web_token_may_come_from_a_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str | None, problem: str | None
) -> None:
    if content is not None:
        (tmp_path / "web.token").write_text(content)
    path = config(tmp_path, web={"writes": True, "token_file": "web.token"})
    code = main(["check", "-c", str(path)])
    err = capsys.readouterr().err
    if problem is None:
        assert code == 0, err
    else:
        assert code == 2 and f"{path}: web.token_file: " in err and problem in err


def test_a_token_and_a_token_file_are_one_too_many(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = config(tmp_path, web={"token": "a-long-enough-token", "token_file": "web.token"})
    assert main(["check", "-c", str(path)]) == 2
    assert "token and token_file: give one, not both" in capsys.readouterr().err
