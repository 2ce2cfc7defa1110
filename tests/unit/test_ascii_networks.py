"""CiA 309-3 net addressing over several CAN networks, without I/O: networks are numbered 1.. in
configured order; ``[seq] net node r ...`` and ``set network N`` address them; a request
without a net goes to the first network or the one ``set network`` chose; a net past the last
is ERROR:106, a node that is not on that net ERROR:107; event lines carry the node's net."""

from __future__ import annotations

from canopen_gateway.ascii.protocol import (
    EventTracker,
    HealthSample,
    NmtCommand,
    SdoUpload,
    Session,
)

#: net 1 (line1): node ids 1 and 125; net 2 (line2): node ids 1 and 2
NETWORKS = {1: [1, 125], 2: [1, 2]}


def session(writes: bool = True) -> Session:
    return Session([], writes=writes, version="1.2.3", networks=NETWORKS)


def test_net_and_node_address_a_node_of_that_network() -> None:
    call = session().handle("[1] 2 1 r 0x1008 0 vs")
    assert isinstance(call, SdoUpload)
    assert (call.net, call.node_id, call.index) == (2, 1, 0x1008)


def test_without_a_net_the_first_network_is_addressed() -> None:
    call = session().handle("[1] 125 r 0x1000 0")
    assert isinstance(call, SdoUpload) and (call.net, call.node_id) == (1, 125)


def test_set_network_chooses_the_default_net() -> None:
    s = session()
    assert s.handle("[1] set network 2") == ["[1] OK"]
    call = s.handle("[2] 2 r 0x1000 0")
    assert isinstance(call, SdoUpload) and (call.net, call.node_id) == (2, 2)
    assert s.handle("[3] 125 r 0x1000 0") == ["[3] ERROR:107"]  # node 125 is on net 1


def test_a_net_past_the_last_is_unsupported_net() -> None:
    s = session()
    assert s.handle("[7] 3 1 r 0x1000 0") == ["[7] ERROR:106"]
    assert s.handle("[8] set network 3") == ["[8] ERROR:106"]
    assert s.handle("[9] 0 1 r 0x1000 0") == ["[9] ERROR:106"]  # net 0: no network, either way
    assert s.handle("[10] set network 0") == ["[10] ERROR:106"]


def test_a_node_not_on_that_net_is_unsupported_node() -> None:
    assert session().handle("[9] 2 125 r 0x1000 0") == ["[9] ERROR:107"]


def test_set_node_checks_the_node_on_the_net_given() -> None:
    s = session()
    assert s.handle("[1] 2 set node 2") == ["[1] OK"]
    assert s.handle("[2] 1 set node 2") == ["[2] ERROR:107"]


def test_nmt_to_node_zero_of_a_net_is_every_node_of_that_network() -> None:
    call = session().handle("[4] 2 0 start")
    assert isinstance(call, NmtCommand) and (call.net, call.node_id, call.command) == (2, 0, "start")


def test_event_lines_carry_the_nodes_net_and_one_node_id_on_two_nets_is_two_nodes() -> None:
    t = EventTracker()
    up = HealthSample(alive=True, boot_count=1, emcy_count=0, supervision="heartbeat")
    rebooted = HealthSample(alive=True, boot_count=2, emcy_count=0, supervision="heartbeat")
    t.update(1, up, net=1)
    t.update(1, up, net=2)
    assert t.update(1, rebooted, net=2) == ["2 1 BOOT_UP"]
    assert t.update(1, up, net=1) == []  # net 1's node 1 did not boot
