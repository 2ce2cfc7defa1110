"""Deployment files hold together: compose, Kubernetes, systemd, Zenoh router, Dockerfile, configs.

Structural checks with what .venv has (YAML load, zenoh's own config parser, the gateway's
config loader); the image itself is built and run by deploy/container-test.sh.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml

from canopen_gateway.config import load_config
from tests.helpers import resolved

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy"
CONFIG_PATH = "/etc/canopen-gateway/config.yaml"


def load_yaml(path: Path) -> dict:
    return yaml.safe_load(path.read_text(encoding="utf-8"))


def load_yaml_all(path: Path) -> list[dict]:
    return [doc for doc in yaml.safe_load_all(path.read_text(encoding="utf-8")) if doc]


# --- configuration files ------------------------------------------------------------------------
@pytest.mark.parametrize(
    "path",
    [
        "config/demo.yaml",
        "deploy/config/demo-remote.yaml",
        "deploy/config/gateway.yaml",
        "deploy/config/fleet-line1.yaml",
        "deploy/config/fleet-line2.yaml",
        "deploy/config/pair.yaml",
    ],
)
def test_shipped_configs_pass_the_gateway_config_checks(path):
    cfg = load_config(ROOT / path, environ={})
    assert cfg.nodes, f"{path} configures no node"


def test_demo_remote_config_joins_the_can_bus_server_and_simulates_nothing_itself():
    cfg = load_config(DEPLOY / "config/demo-remote.yaml", environ={})
    assert cfg.can.bus_kwargs()["interface"] == "remote"
    assert cfg.can.bus_kwargs()["channel"] == "ws://127.0.0.1:54701/"
    assert cfg.simulate.nodes == []
    demo = load_config(ROOT / "config/demo.yaml", environ={})
    assert [(n.name, n.node_id, n.profile) for n in cfg.nodes] == [
        (n.name, n.node_id, n.profile) for n in demo.nodes
    ]


def test_container_env_overrides_reach_the_health_section():
    cfg = load_config(
        ROOT / "config/demo.yaml",
        environ={
            "CANOPEN_GATEWAY__HEALTH__HOST": "0.0.0.0",
            "CANOPEN_GATEWAY__HEALTH__PORT": "8080",
        },
    )
    assert (cfg.health.host, cfg.health.port) == ("0.0.0.0", 8080)


# --- docker compose -----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def compose() -> dict:
    return load_yaml(DEPLOY / "docker-compose.yml")


def test_compose_gateway_uses_host_network_restarts_and_mounts_its_config(compose):
    gw = compose["services"]["gateway"]
    assert gw["network_mode"] == "host"
    assert gw["restart"] == "unless-stopped"
    assert "profiles" not in gw
    mounts = [v.rsplit(":", 2) for v in gw["volumes"]]
    assert any(target == CONFIG_PATH and mode == "ro" for _source, target, mode in mounts)
    assert gw["build"]["context"] == ".."
    assert (DEPLOY / gw["build"]["context"] / gw["build"]["dockerfile"]).is_file()


def test_compose_default_gateway_config_exists(compose):
    source = compose["services"]["gateway"]["volumes"][0].rsplit(":", 2)[0]
    default = re.fullmatch(r"\$\{GATEWAY_CONFIG:-(.+)\}", source).group(1)
    assert (DEPLOY / default).is_file()


def test_compose_zenoh_router_runs_the_router_config(compose):
    router = compose["services"]["zenoh-router"]
    assert router["image"].startswith("eclipse/zenoh")
    source, target, _ = router["volumes"][0].split(":")
    assert (DEPLOY / source).is_file()
    assert router["command"] == ["-c", target]


def test_compose_demo_profile_has_bus_server_and_simulator(compose):
    services = compose["services"]
    canbus, sim = services["canbus"], services["sim"]
    assert canbus["profiles"] == ["demo"] and sim["profiles"] == ["demo"]
    assert canbus["entrypoint"] == ["python", "-m", "can_remote"]
    assert canbus["command"] == ["-i", "virtual", "-c", "vbus0", "-H", "0.0.0.0", "-p", "54701"]
    assert canbus["ports"] == ["127.0.0.1:54701:54701"]  # never on the LAN
    assert canbus["init"] is True  # can_remote ignores SIGTERM as PID 1
    assert sim["command"] == ["simulate", "-c", "/etc/canopen-gateway/demo-remote.yaml"]
    assert sim["environment"]["CANOPEN_GATEWAY__CAN__CHANNEL"] == "ws://canbus:54701/"


def test_compose_services_all_reference_known_images(compose):
    images = {s["image"].split(":")[0] for s in compose["services"].values()}
    assert images == {"canopen-gateway", "eclipse/zenoh"}


# --- Kubernetes ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def k8s() -> dict[str, dict]:
    kustomization = load_yaml(DEPLOY / "k8s/kustomization.yaml")
    docs = [
        doc for name in kustomization["resources"] for doc in load_yaml_all(DEPLOY / "k8s" / name)
    ]
    return {doc["kind"]: doc for doc in docs}


def test_k8s_deployment_uses_host_network_single_replica_recreate(k8s):
    spec = k8s["Deployment"]["spec"]
    assert spec["replicas"] == 1
    assert spec["strategy"]["type"] == "Recreate"
    pod = spec["template"]["spec"]
    assert pod["hostNetwork"] is True
    assert pod["dnsPolicy"] == "ClusterFirstWithHostNet"
    assert spec["selector"]["matchLabels"].items() <= spec["template"]["metadata"]["labels"].items()


def test_k8s_probes_hit_the_health_endpoints_on_the_health_port(k8s):
    container = k8s["Deployment"]["spec"]["template"]["spec"]["containers"][0]
    ports = {p["name"]: p["containerPort"] for p in container["ports"]}
    env = {e["name"]: e["value"] for e in container["env"]}
    assert ports["health"] == int(env["CANOPEN_GATEWAY__HEALTH__PORT"]) == 8080
    assert env["CANOPEN_GATEWAY__HEALTH__HOST"] == "0.0.0.0"
    assert container["readinessProbe"]["httpGet"] == {"path": "/healthz", "port": "health"}
    assert container["livenessProbe"]["httpGet"] == {"path": "/livez", "port": "health"}


def test_k8s_container_is_non_root_read_only_with_resources(k8s):
    pod = k8s["Deployment"]["spec"]["template"]["spec"]
    container = pod["containers"][0]
    assert pod["securityContext"]["runAsNonRoot"] is True
    assert pod["securityContext"]["runAsUser"] == 10001
    assert container["securityContext"]["readOnlyRootFilesystem"] is True
    assert container["securityContext"]["capabilities"]["drop"] == ["ALL"]
    assert {"cpu", "memory"} <= container["resources"]["requests"].keys()
    assert "memory" in container["resources"]["limits"]


def test_k8s_config_map_is_mounted_as_the_config_file_and_matches_the_plant_config(k8s):
    pod = k8s["Deployment"]["spec"]["template"]["spec"]
    container = pod["containers"][0]
    volumes = {v["name"]: v for v in pod["volumes"]}
    mount = next(
        m for m in container["volumeMounts"] if m["mountPath"] == str(Path(CONFIG_PATH).parent)
    )
    assert volumes[mount["name"]]["configMap"]["name"] == k8s["ConfigMap"]["metadata"]["name"]
    assert container["args"] == ["run", "-c", CONFIG_PATH]
    text = k8s["ConfigMap"]["data"][Path(CONFIG_PATH).name]
    assert text == (DEPLOY / "config/gateway.yaml").read_text(encoding="utf-8")


# --- systemd ------------------------------------------------------------------------------------
def unit_settings(path: Path) -> dict[str, list[str]]:
    settings: dict[str, list[str]] = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        if line and not line.startswith(("#", "[")) and "=" in line:
            key, value = line.split("=", 1)
            settings.setdefault(key, []).append(value)
    return settings


def test_systemd_unit_runs_the_gateway_hardened():
    unit = unit_settings(DEPLOY / "systemd/canopen-gateway.service")
    # the config stays root's (0600): the service reads the copy systemd hands it
    assert unit["LoadCredential"] == ["config.yaml:/etc/canopen-gateway/config.yaml"]
    assert unit["ExecStart"] == [
        "/opt/canopen-gateway/bin/canopen-gateway run -c ${CREDENTIALS_DIRECTORY}/config.yaml"
    ]
    assert int(unit["LimitNOFILE"][0]) >= 8192  # room above the connection caps
    for key, value in {
        "NoNewPrivileges": "yes",
        "ProtectSystem": "strict",
        "ProtectHome": "yes",
        "PrivateTmp": "yes",
        "DynamicUser": "yes",
        "Restart": "on-failure",
    }.items():
        assert unit[key] == [value], key
    assert "AF_CAN" in unit["RestrictAddressFamilies"][0].split()
    # the gateway says READY=1 and pings the watchdog (canopen_gateway.runtime.sd_notify)
    assert unit["Type"] == ["notify"] and int(unit["WatchdogSec"][0]) > 0


def test_can0_network_file_sets_the_bit_rate():
    unit = unit_settings(DEPLOY / "systemd/80-can0.network")
    assert unit["Name"] == ["can0"]
    assert unit["BitRate"] == ["500K"]


# --- Zenoh router -------------------------------------------------------------------------------
def test_router_config_is_accepted_by_zenoh():
    zenoh = pytest.importorskip("zenoh")
    conf = zenoh.Config.from_file(str(DEPLOY / "zenoh/router.json5"))
    assert conf.get_json("mode") == '"router"'
    assert "7447" in conf.get_json("listen/endpoints")


def router_acl() -> dict:
    zenoh = pytest.importorskip("zenoh")
    conf = zenoh.Config.from_file(str(DEPLOY / "zenoh/router.json5"))
    assert json.loads(conf.get_json("transport/auth/usrpwd/dictionary_file")) == "/run/secrets/zenoh-users"
    return json.loads(conf.get_json("access_control"))


def test_the_router_is_closed_by_default_and_ships_no_password():
    acl = router_acl()
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    text = (DEPLOY / "zenoh/router.json5").read_text()
    assert "change-me" not in text and not re.search(r"^\s*password\s*:", text, re.M)
    for path in [*DEPLOY.rglob("*.yml"), *DEPLOY.rglob("*.yaml"), *(ROOT / "config").glob("*.yaml")]:
        assert "change-me" not in path.read_text(), path


def gateway_logins() -> dict[str, list[str]]:
    """router.json5: a gateway's login -> the key expressions its rule lets it publish on."""
    acl = router_acl()
    rules = {r["id"]: r for r in acl["rules"]}
    subjects = {s["id"]: s.get("usernames") or [] for s in acl["subjects"]}
    out: dict[str, list[str]] = {}
    for policy in acl["policies"]:
        for subject in policy["subjects"]:
            for user in subjects[subject]:
                for rule in policy["rules"]:
                    if "put" in rules[rule]["messages"] and rules[rule]["permission"] == "allow":
                        out.setdefault(user, []).extend(rules[rule]["key_exprs"])
    return out


@pytest.mark.parametrize("name", ["docker-compose.yml", "docker-compose.fleet.yml", "docker-compose.pair.yml"])
def test_compose_gateways_log_in_to_the_closed_router_as_their_prefixs_gateway(name):
    compose = load_yaml(DEPLOY / name)
    router = compose["services"]["zenoh-router"]
    assert router["secrets"] == [{"source": "zenoh-users", "target": "zenoh-users"}]
    secrets = compose["secrets"]
    assert secrets["zenoh-users"]["file"] == "./zenoh/secrets/users.txt"
    logins = gateway_logins()
    made = re.search(r"^DEFAULT_LOGINS=\((.*)\)$", (DEPLOY / "zenoh/make-secrets.sh").read_text(), re.M)
    assert made is not None and set(logins) <= set(made.group(1).split())
    for svc_name, svc in compose["services"].items():
        if svc.get("command", [None])[0] == "simulate" or not svc_name.startswith("gateway"):
            continue
        env = {k: str(v) for k, v in svc["environment"].items()}
        user = re.sub(r"\$\{GATEWAY_LOGIN:-(.+)\}", r"\1", env["CANOPEN_GATEWAY__ZENOH__AUTH__USER"])
        assert env["CANOPEN_GATEWAY__ZENOH__AUTH__PASSWORD_FILE"] == "/run/secrets/zenoh-password"
        (secret,) = [x for x in svc["secrets"] if x["target"] == "zenoh-password"]
        file = re.sub(r"\$\{GATEWAY_LOGIN:-(.+)\}", r"\1", secrets[secret["source"]]["file"])
        assert file == f"./zenoh/secrets/{user}.password", svc_name
        mount = next(v for v in svc["volumes"] if v.rsplit(":", 2)[1] == CONFIG_PATH)
        source = re.sub(r"\$\{GATEWAY_CONFIG:-(.+)\}", r"\1", mount.rsplit(":", 2)[0])
        cfg = load_config(DEPLOY / source, environ=env)
        prefix = cfg.zenoh.key_prefix(cfg.gateway.name)
        assert f"{prefix}/**" in logins[user], (svc_name, user, prefix)
        assert svc["ulimits"]["nofile"]["soft"] >= 8192  # room above the connection caps


# --- fleet --------------------------------------------------------------------------------------
def test_fleet_compose_runs_a_router_and_two_gateways_under_their_own_prefixes():
    compose = load_yaml(DEPLOY / "docker-compose.fleet.yml")
    services = compose["services"]
    assert "demo" not in services["zenoh-router"].get("profiles", [])
    gateways = {n: s for n, s in services.items() if n.startswith("gateway-")}
    assert len(gateways) == 2
    prefixes = set()
    for svc in gateways.values():
        assert svc["profiles"] == ["demo"]
        (mount,) = [v for v in svc["volumes"] if v.endswith(f":{CONFIG_PATH}:ro")]
        cfg = load_config(DEPLOY / mount.split(":")[0], environ={})
        assert cfg.zenoh.mode == "client" and cfg.zenoh.connect == ["tcp/zenoh-router:7447"]
        assert cfg.simulated_nodes() == cfg.nodes  # demo: every device simulated
        prefixes.add(cfg.zenoh.key_prefix(cfg.gateway.name))
    assert prefixes == {"canopen/line1", "canopen/line2"}


# --- Dockerfile ---------------------------------------------------------------------------------
def test_dockerfile_contract():
    text = (ROOT / "Dockerfile").read_text(encoding="utf-8")
    assert "ARG BASE_IMAGE=python:3.11-slim" in text
    assert "python3 -m venv" in text
    assert re.search(r"^USER \d+:\d+$", text, re.M), "runs as a numeric non-root user"
    # no config of its own: the demo beside it, run only when asked for (CLI: demo_config)
    assert CONFIG_PATH not in re.findall(r"^COPY \S+ (\S+)$", text, re.M)
    assert "COPY config/demo.yaml /etc/canopen-gateway/demo.yaml" in text
    assert "CANOPEN_GATEWAY_DEMO_CONFIG=/etc/canopen-gateway/demo.yaml" in text
    assert 'ENTRYPOINT ["canopen-gateway"]' in text
    assert f'CMD ["run", "-c", "{CONFIG_PATH}"]' in text
    assert "CANOPEN_GATEWAY__HEALTH__PORT=8080" in text
    assert "CANOPEN_GATEWAY__HEALTH__HOST=0.0.0.0" in text
    healthcheck = re.search(r"^HEALTHCHECK .*\n.*$", text, re.M).group(0)
    assert "/healthz" in healthcheck and "urllib" in healthcheck
    assert text.count("FROM ${BASE_IMAGE}") == 2, "build and runtime stages on the same base"


def test_dockerignore_admits_only_what_the_build_copies():
    lines = [
        line
        for line in (ROOT / ".dockerignore").read_text(encoding="utf-8").splitlines()
        if line and not line.startswith("#")
    ]
    assert lines[0] == "*", "everything is excluded first"
    for needed in (
        "!pyproject.toml",
        "!README.md",
        "!canopen_gateway/",
        "!config/demo.yaml",
        "!deploy/config/",
    ):
        assert needed in lines


# --- a hot-standby pair -------------------------------------------------------------------------
PAIR_ENV = "CANOPEN_GATEWAY__MASTER__REDUNDANCY__"


def pair_configs(envs: list[dict[str, str]]) -> list:
    """deploy/config/pair.yaml as each gateway of the pair loads it (its environment applied)."""
    return [load_config(DEPLOY / "config/pair.yaml", environ=env) for env in envs]


def test_the_pair_config_gives_each_gateway_no_warning():
    """deploy/config/pair.yaml as gateway A and as gateway B load it: `check` warns of nothing
    (a SYNC producer for the SYNC-driven TPDOs, a take-over every node survives)."""
    from canopen_gateway.checks import config_warnings

    b = {f"{PAIR_ENV}NODE_ID": "121", f"{PAIR_ENV}PRIORITY": "1", f"{PAIR_ENV}PEER_NODE_ID": "120"}
    for cfg in pair_configs([{}, b]):
        assert config_warnings(cfg, resolved(cfg)) == []


def test_pair_compose_runs_two_gateways_of_one_image_and_config_with_own_ids():
    from canopen_gateway.checks import pair_problems

    compose = load_yaml(DEPLOY / "docker-compose.pair.yml")
    services = compose["services"]
    a, b = services["gateway-a"], services["gateway-b"]
    assert a["image"] == b["image"] and a["volumes"][0] == b["volumes"][0]  # the config
    assert a["network_mode"] == b["network_mode"] == "host"
    source = a["volumes"][0].rsplit(":", 2)[0]
    assert re.fullmatch(r"\$\{GATEWAY_CONFIG:-\./config/pair\.yaml\}", source)
    envs = [{k: str(v) for k, v in s["environment"].items()} for s in (a, b)]
    cfg_a, cfg_b = pair_configs(envs)
    assert (cfg_a.master.redundancy.node_id, cfg_a.master.redundancy.priority) == (120, 0)
    assert (cfg_b.master.redundancy.node_id, cfg_b.master.redundancy.priority) == (121, 1)
    assert pair_problems(cfg_a, cfg_b, resolved(cfg_a), resolved(cfg_b)) == []
    # one machine: each its own ports
    for key in ("MODBUS__PORT", "HEALTH__PORT", "ZENOH__LISTEN"):
        assert envs[0][f"CANOPEN_GATEWAY__{key}"] != envs[1][f"CANOPEN_GATEWAY__{key}"]
    assert cfg_a.zenoh.refuse_duplicate_prefix is False  # both run under canopen/line1


@pytest.fixture(scope="module")
def k8s_pair() -> dict[str, dict]:
    kustomization = load_yaml(DEPLOY / "k8s/pair/kustomization.yaml")
    docs = [
        doc for name in kustomization["resources"] for doc in load_yaml_all(DEPLOY / "k8s/pair" / name)
    ]
    return {doc["metadata"]["name"]: doc for doc in docs}


def test_k8s_pair_is_two_deployments_on_two_machines_with_the_pairs_config(k8s_pair):
    from canopen_gateway.checks import pair_problems

    cm = k8s_pair["canopen-gateway-pair-config"]
    assert cm["data"]["config.yaml"] == (DEPLOY / "config/pair.yaml").read_text(encoding="utf-8")
    envs = []
    for name in ("canopen-gateway-a", "canopen-gateway-b"):
        spec = k8s_pair[name]["spec"]
        assert spec["replicas"] == 1 and spec["strategy"]["type"] == "Recreate"
        pod = spec["template"]["spec"]
        assert pod["hostNetwork"] is True
        anti = pod["affinity"]["podAntiAffinity"]["requiredDuringSchedulingIgnoredDuringExecution"]
        assert anti[0]["topologyKey"] == "kubernetes.io/hostname"
        assert anti[0]["labelSelector"]["matchLabels"].items() <= spec["template"]["metadata"]["labels"].items()
        assert spec["selector"]["matchLabels"].items() <= spec["template"]["metadata"]["labels"].items()
        container = pod["containers"][0]
        assert container["args"] == ["run", "-c", CONFIG_PATH]
        volumes = {v["name"]: v for v in pod["volumes"]}
        assert volumes["config"]["configMap"]["name"] == cm["metadata"]["name"]
        envs.append({e["name"]: e["value"] for e in container["env"] if e["name"].startswith(PAIR_ENV)})
    cfg_a, cfg_b = pair_configs(envs)
    assert (cfg_a.master.redundancy.priority, cfg_b.master.redundancy.priority) == (0, 1)
    assert pair_problems(cfg_a, cfg_b, resolved(cfg_a), resolved(cfg_b)) == []


# --- the journal's volume -----------------------------------------------------------------------
STATE_DIR = "/var/lib/canopen-gateway"
JOURNAL_PATH = f"{STATE_DIR}/journal"


def test_the_image_puts_the_journal_in_its_volume():
    text = (ROOT / "Dockerfile").read_text(encoding="utf-8")
    assert f"CANOPEN_GATEWAY__JOURNAL__PATH={JOURNAL_PATH}" in text
    assert f'VOLUME ["{STATE_DIR}"]' in text
    assert f"chown -R 10001:10001 {STATE_DIR}" in text  # what a fresh named volume copies


@pytest.mark.parametrize(
    "name", ["docker-compose.yml", "docker-compose.pair.yml", "docker-compose.fleet.yml"]
)
def test_compose_gateways_each_keep_the_journal_in_a_named_volume_of_their_own(name):
    compose = load_yaml(DEPLOY / name)
    gateways = {
        n: s
        for n, s in compose["services"].items()
        if s["image"].startswith("canopen-gateway") and "command" not in s and "entrypoint" not in s
    }
    assert gateways
    used = []
    for service, svc in gateways.items():
        assert svc["read_only"] is True
        (volume,) = [v.split(":")[0] for v in svc["volumes"] if v.split(":")[1] == STATE_DIR]
        assert volume in compose["volumes"], f"{service}: {volume} is not a named volume"
        used.append(volume)
    assert len(set(used)) == len(used), "each gateway its own journal"


def k8s_journal_claims(kustomization_dir: Path) -> tuple[list[dict], set[str]]:
    kustomization = load_yaml(kustomization_dir / "kustomization.yaml")
    docs = [
        d for name in kustomization["resources"] for d in load_yaml_all(kustomization_dir / name)
    ]
    claims = {d["metadata"]["name"] for d in docs if d["kind"] == "PersistentVolumeClaim"}
    return [d for d in docs if d["kind"] == "Deployment"], claims


@pytest.mark.parametrize("where", ["k8s", "k8s/pair"])
def test_k8s_gateways_each_keep_the_journal_on_a_claim_of_their_own_writable_by_10001(where):
    deployments, claims = k8s_journal_claims(DEPLOY / where)
    used = []
    for deployment in deployments:
        pod = deployment["spec"]["template"]["spec"]
        assert pod["securityContext"]["fsGroup"] == 10001
        container = pod["containers"][0]
        assert container["securityContext"]["readOnlyRootFilesystem"] is True
        env = {e["name"]: e.get("value") for e in container["env"]}
        assert env["CANOPEN_GATEWAY__JOURNAL__PATH"] == JOURNAL_PATH
        (mount,) = [m for m in container["volumeMounts"] if m["mountPath"] == STATE_DIR]
        volumes = {v["name"]: v for v in pod["volumes"]}
        claim = volumes[mount["name"]]["persistentVolumeClaim"]["claimName"]
        assert claim in claims
        used.append(claim)
    assert len(used) == len(deployments) == len(set(used)) >= 1


def test_systemd_unit_keeps_the_journal_in_its_state_directory():
    unit = unit_settings(DEPLOY / "systemd/canopen-gateway.service")
    assert unit["StateDirectory"] == ["canopen-gateway"]  # /var/lib/canopen-gateway, kept
    env = dict(item.split("=", 1) for line in unit["Environment"] for item in line.split())
    assert env["CANOPEN_GATEWAY__JOURNAL__PATH"] == JOURNAL_PATH
