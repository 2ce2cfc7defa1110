"""The caps on Modbus connections (``modbus.admission``): per client address, in total, and
which connection gives way to a client in ``allowed_networks`` when the total is reached."""

from __future__ import annotations

from canopen_gateway.modbus.admission import Admission

PLC = "10.0.0.5"


def trusted(address: str) -> bool:
    return address.startswith("10.")


def test_a_client_at_its_own_cap_is_refused_while_others_are_admitted() -> None:
    a = Admission(max_total=64, max_per_client=2, trusted=trusted)
    for _ in range(2):
        assert a.decide("192.168.1.9") == "admit"
        a.opened("192.168.1.9")
    assert a.decide("192.168.1.9") == "per_client"
    assert a.decide(PLC) == "admit"


def test_a_full_gateway_gives_an_untrusted_place_to_the_plc_never_to_a_stranger() -> None:
    a = Admission(max_total=3, max_per_client=3, trusted=trusted)
    for _ in range(3):
        a.opened("192.168.1.9")
    assert a.decide("192.168.1.10") == "total"
    assert a.decide(PLC) == "evict"


def test_a_gateway_full_of_trusted_clients_refuses_the_next_one() -> None:
    a = Admission(max_total=2, max_per_client=2, trusted=trusted)
    a.opened(PLC)
    a.opened("10.0.0.6")
    assert a.decide("10.0.0.7") == "total"


def test_closing_frees_the_place_and_the_counts_say_why_connections_were_closed() -> None:
    a = Admission(max_total=1, max_per_client=1, trusted=trusted)
    a.opened("192.168.1.9")
    assert a.decide("192.168.1.9") == "per_client"
    a.closed("192.168.1.9")
    assert a.decide("192.168.1.9") == "admit"
    a.count("per_client")
    a.count("per_client")
    a.count("idle")
    assert a.counts() == (0, {"per_client": 2, "idle": 1})
    assert a.untrusted == 0 and a.per_client == {}
