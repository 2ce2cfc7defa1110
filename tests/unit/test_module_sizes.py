"""Modules stay small enough to read: each of these packages' modules is under 550 lines, split
by role where one grew past it (the profile loader, the simulated node, the command service,
the Modbus datastore)."""

from __future__ import annotations

from pathlib import Path

import pytest

GATEWAY = Path(__file__).resolve().parents[2] / "canopen_gateway"
MAX_LINES = 550
PACKAGES = ("profiles", "sim", "commands", "modbus")


@pytest.mark.parametrize("package", PACKAGES)
def test_every_module_of_the_package_is_under_550_lines(package: str) -> None:
    assert (GATEWAY / package / "__init__.py").is_file()  # a package, its modules by role
    too_long = {
        str(p.relative_to(GATEWAY)): n
        for p in sorted((GATEWAY / package).rglob("*.py"))
        if (n := len(p.read_text(encoding="utf-8").splitlines())) >= MAX_LINES
    }
    assert too_long == {}


def test_no_module_of_the_gateway_is_over_550_lines() -> None:
    too_long = {
        str(p.relative_to(GATEWAY)): n
        for p in sorted(GATEWAY.rglob("*.py"))
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert too_long == {}


def test_the_profiles_package_still_offers_its_public_names() -> None:
    import canopen_gateway.profiles as profiles

    for name in profiles.__all__:
        assert getattr(profiles, name) is not None
    assert {"LoadedProfile", "ProfileError", "load_profile", "load_node_profile",
            "expected_identity", "import_eds", "PROFILE_DIR"} <= set(profiles.__all__)  # fmt: skip


def test_the_commands_package_still_offers_its_public_names() -> None:
    import canopen_gateway.commands as commands

    for name in commands.__all__:
        assert getattr(commands, name) is not None
    assert {"CommandService", "NodeInfo", "SDO_TYPES", "check_sdo_type", "check_value",
            "type_range", "writable_mask", "bit_names"} <= set(commands.__all__)  # fmt: skip
