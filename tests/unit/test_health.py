"""Health document and Prometheus metrics: pure, no sockets."""

from __future__ import annotations

import math

from prometheus_client.parser import text_string_to_metric_families

from canopen_gateway.http.metrics import Metrics, NodeSample, nmt_state_code
from canopen_gateway.http.server import NOT_READY, READY, build_status, pair_status


class FakeClock:
    def __init__(self, now_s: float = 1000.0) -> None:
        self.now_s = now_s

    def __call__(self) -> float:
        return self.now_s


def scrape(metrics: Metrics) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    """Parse the exposition text back, as Prometheus would: {(sample name, labels): value}."""
    samples = {}
    for family in text_string_to_metric_families(metrics.render().decode()):
        for s in family.samples:
            samples[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return samples


def test_ready_when_bus_open_and_enabled_adapters_up():
    doc = build_status(bus_open=True, modbus_up=True, zenoh_up=None, nodes={})
    assert doc["status"] == READY
    assert doc["reasons"] == []
    assert doc["zenoh_up"] is None


def test_not_ready_names_each_reason_in_words():
    doc = build_status(bus_open=False, modbus_up=True, zenoh_up=False)
    assert doc["status"] == NOT_READY
    assert doc["reasons"] == ["CAN bus is not open", "Zenoh session is not open"]


def test_a_dead_node_is_reported_but_keeps_the_gateway_ready():
    doc = build_status(
        bus_open=True,
        modbus_up=True,
        zenoh_up=True,
        nodes={"display1": {"alive": False, "nmt_state": None}},
    )
    assert doc["status"] == READY
    assert doc["nodes"]["display1"]["alive"] is False


def test_hot_path_counters_are_plain_ints_read_at_scrape_time():
    metrics = Metrics(process_metrics=False)
    counters = metrics.counters
    for _ in range(1000):
        counters.frames_in += 1
    counters.frames_out += 7
    counters.bus_errors += 2
    counters.bursts += 3
    counters.zenoh_publications += 5
    samples = scrape(metrics)
    assert samples[("canopen_gateway_frames_in_total", ())] == 1000
    assert samples[("canopen_gateway_frames_out_total", ())] == 7
    assert samples[("canopen_gateway_bus_errors_total", ())] == 2
    assert samples[("canopen_gateway_can_bursts_total", ())] == 3
    assert samples[("canopen_gateway_zenoh_publications_total", ())] == 5
    counters.frames_in += 1
    assert scrape(metrics)[("canopen_gateway_frames_in_total", ())] == 1001


def test_labelled_counters_carry_node_op_code_and_function():
    metrics = Metrics(process_metrics=False)
    metrics.decode_error("encoder1", "length")
    metrics.decode_error("encoder1", "length")
    metrics.emcy("display1")
    metrics.sdo_request("encoder1", "read")
    metrics.sdo_abort("encoder1", 0x06090011)
    metrics.modbus_request(4)
    metrics.modbus_request(0x41)
    metrics.modbus_exception(0x0B)
    samples = scrape(metrics)
    assert (
        samples[
            ("canopen_gateway_decode_errors_total", (("node", "encoder1"), ("reason", "length")))
        ]
        == 2
    )
    assert samples[("canopen_gateway_emcy_total", (("node", "display1"),))] == 1
    assert (
        samples[("canopen_gateway_sdo_requests_total", (("node", "encoder1"), ("op", "read")))] == 1
    )
    assert (
        samples[
            ("canopen_gateway_sdo_aborts_total", (("code", "0x06090011"), ("node", "encoder1")))
        ]
        == 1
    )
    assert (
        samples[("canopen_gateway_modbus_requests_total", (("function", "read_input_registers"),))]
        == 1
    )
    assert samples[("canopen_gateway_modbus_requests_total", (("function", "0x41"),))] == 1
    assert (
        samples[
            (
                "canopen_gateway_modbus_exceptions_total",
                (("code", "gateway_target_device_failed_to_respond"),),
            )
        ]
        == 1
    )


def test_sdo_latency_is_a_histogram_per_node():
    metrics = Metrics(process_metrics=False)
    metrics.observe_sdo_latency("encoder1", 0.004)
    metrics.observe_sdo_latency("encoder1", 0.3)
    samples = scrape(metrics)
    node = ("node", "encoder1")
    assert samples[("canopen_gateway_sdo_latency_seconds_count", (node,))] == 2
    assert samples[("canopen_gateway_sdo_latency_seconds_bucket", (("le", "0.005"), node))] == 1
    assert samples[("canopen_gateway_sdo_latency_seconds_bucket", (("le", "0.5"), node))] == 2
    assert math.isclose(samples[("canopen_gateway_sdo_latency_seconds_sum", (node,))], 0.304)


def test_node_gauges_are_computed_by_the_source_at_each_scrape():
    clock = FakeClock()
    last_data_s = {"encoder1": 999.5}
    metrics = Metrics(clock=clock, process_metrics=False)
    metrics.set_node_source(
        lambda: [
            NodeSample("encoder1", "OPERATIONAL", True, clock() - last_data_s["encoder1"]),
            NodeSample("display1", None, False, None),
        ]
    )
    samples = scrape(metrics)
    enc, disp = (("node", "encoder1"),), (("node", "display1"),)
    assert samples[("canopen_gateway_node_nmt_state", enc)] == 5
    assert samples[("canopen_gateway_node_alive", enc)] == 1
    assert samples[("canopen_gateway_node_data_age_seconds", enc)] == 0.5
    assert samples[("canopen_gateway_node_nmt_state", disp)] == -1
    assert samples[("canopen_gateway_node_alive", disp)] == 0
    assert samples[("canopen_gateway_node_data_age_seconds", disp)] == math.inf
    clock.now_s += 2.0
    assert scrape(metrics)[("canopen_gateway_node_data_age_seconds", enc)] == 2.5


def test_uptime_counts_from_construction():
    clock = FakeClock(50.0)
    metrics = Metrics(clock=clock, process_metrics=False)
    clock.now_s = 62.5
    assert scrape(metrics)[("canopen_gateway_uptime_seconds", ())] == 12.5


def test_a_failing_node_source_leaves_the_rest_of_the_scrape_intact(caplog):
    metrics = Metrics(process_metrics=False)
    metrics.counters.frames_in = 3

    def broken():
        raise RuntimeError("image gone")

    metrics.set_node_source(broken)
    samples = scrape(metrics)
    assert samples[("canopen_gateway_frames_in_total", ())] == 3
    assert not any(name == "canopen_gateway_node_alive" for name, _ in samples)
    assert "node source for metrics failed" in caplog.text


def test_two_gateways_in_one_process_have_separate_registries():
    a, b = Metrics(), Metrics()
    a.counters.frames_in = 10
    assert scrape(a)[("canopen_gateway_frames_in_total", ())] == 10
    assert scrape(b)[("canopen_gateway_frames_in_total", ())] == 0
    assert ("process_open_fds", ()) in scrape(a)


def test_nmt_states_map_to_heartbeat_state_bytes():
    # CiA 301 7.2.8.3.2.2: 0 boot-up, 4 stopped, 5 operational, 127 pre-operational
    assert [nmt_state_code(s) for s in ("INITIALISING", "STOPPED", "OPERATIONAL")] == [0, 4, 5]
    assert nmt_state_code("pre-operational") == 127
    assert nmt_state_code(127) == 127
    assert nmt_state_code("SLEEP") == -1


# ---------------------------------------------------------------------- a hot-standby pair
def test_outside_a_pair_role_and_peer_are_null():
    assert pair_status(None, now_s=5.0, recent_s=0.3) == {"role": None, "peer": None}


def test_the_standby_sees_the_active_peer_by_its_recent_claim():
    doc = pair_status("standby", now_s=10.0, recent_s=0.3, claim=(0, 101, 9.9))
    assert doc["role"] == "standby"
    assert doc["peer"] == {
        "heard": True,
        "role": "active",
        "node_id": 101,
        "priority": 0,
        "claim_age_s": 0.1,
        "heartbeat_age_s": None,
    }


def test_a_claim_older_than_the_takeover_time_is_no_active_peer():
    at = math.nextafter(9.75, 0.0)  # a hair more than the take-over time ago
    doc = pair_status("active", now_s=10.0, recent_s=0.25, claim=(0, 101, at))
    assert doc["peer"]["role"] == "unknown" and doc["peer"]["heard"] is False
    doc = pair_status("active", now_s=10.0, recent_s=0.25, claim=(0, 101, 9.75))
    assert doc["peer"]["role"] == "active"  # exactly the take-over time: still heard


def test_the_active_one_sees_a_standby_peer_by_its_own_heartbeat():
    doc = pair_status(
        "active", now_s=10.0, recent_s=0.3, claim=(0, 101, 2.0), peer_heartbeat_s=9.95
    )
    peer = doc["peer"]
    assert peer["role"] == "standby" and peer["heard"] is True
    assert peer["heartbeat_age_s"] == 0.05 and peer["claim_age_s"] == 8.0
    # never claimed, heartbeat configured: the id is the configured one, the priority unknown
    doc = pair_status("active", now_s=10.0, recent_s=0.3, peer_heartbeat_s=9.9, peer_node_id=102)
    assert doc["peer"]["node_id"] == 102 and doc["peer"]["priority"] is None


def test_the_peer_is_shown_in_the_role_its_own_heartbeat_says_whatever_its_claims_age():
    """A standby whose active peer claimed long ago (there is no periodic 71h) shows it active
    by its heartbeat; an isolated peer shows isolated; a third party's claim is not the peer's."""
    doc = pair_status("standby", now_s=10.0, recent_s=0.3, claim=(0, 101, 2.0),
                      peer_heartbeat_s=9.95, peer_node_id=101, master_id=101, peer_role="active")  # fmt: skip
    assert doc["peer"]["role"] == "active" and doc["master_id"] == 101
    doc = pair_status("active", now_s=10.0, recent_s=0.3, peer_heartbeat_s=9.95, peer_role="isolated")
    assert doc["peer"]["role"] == "isolated" and doc["peer"]["heard"] is True
    doc = pair_status("standby", now_s=10.0, recent_s=0.3, claim=(0, 5, 9.9), peer_node_id=102)
    assert doc["peer"]["node_id"] == 102 and doc["peer"]["role"] == "unknown"


def test_pair_metrics_count_takeovers_and_negotiations_and_gauge_the_role():
    m = Metrics()
    m.counters.pair_takeovers, m.counters.pair_negotiations, m.counters.pair_role = 1, 2, 2
    samples = scrape(m)
    assert samples[("canopen_gateway_pair_takeovers_total", ())] == 1
    assert samples[("canopen_gateway_pair_negotiations_total", ())] == 2
    assert samples[("canopen_gateway_pair_role", ())] == 2



def test_build_info_names_the_package_version_and_python_with_value_1():
    import platform
    from importlib.metadata import version

    samples = scrape(Metrics(process_metrics=False))
    labels = (("python", platform.python_version()), ("version", version("canopen-gateway")))
    assert samples[("canopen_gateway_build_info", labels)] == 1
