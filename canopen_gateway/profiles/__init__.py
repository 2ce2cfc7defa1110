"""Device profiles (overlays on an EDS) and the loader that makes a node's complete profile.

``load_profile("sgh10")`` finds ``canopen_gateway/profiles/sgh10.yaml``; a path to a ``.yaml`` file loads
a user's own profile, its ``eds:`` resolved next to it. The EDS is checked and read by
``canopen_gateway.eds.load_eds``; every object the profile names must exist in it; signal types,
access and transport the profile leaves out are taken from the EDS and the PDO layout.

``load_node_profile(node, base_dir)`` is what the rest of the gateway uses for a configured
node: the profile (or none: an EDS-only node) on the node's EDS or DCF, its PDO layout after the
node's ``tpdo:``/``rpdo:`` settings and PDO writes (``layout``), and a signal for every mapped
object (derived from the EDS where the profile names none). The node is read as a ``NodeSetup``
(``node_setup``), the config-free record ``canopen_gateway.config.NodeConfig.setup`` builds. One result, used by the boot-step
builder, the codecs, the register map, the Zenoh keys and the simulator.

By role: ``loader`` (a profile file on its EDS), ``node_profile`` (one configured node),
``device`` (what the file says of the device: supervision, identity, mapping check),
``node_setup`` (what is read of a node's configuration), ``layout`` (PDO layouts), ``schema``
(the YAML model), ``derived`` (signals derived from a profile). This package re-exports the
public names of the first four, so callers import them from
``canopen_gateway.profiles``.

Imports: profiles.loader, profiles.node_profile, profiles.device, profiles.node_setup. Nothing of bus/, modbus/,
zenoh_bridge/, config.
"""

from canopen_gateway.profiles.device import (
    STALE_EVENT_TIMER_MULTIPLE,
    IdentityCheck,
    device_supervision,
    expected_identity,
    identity_check,
    node_verifies_mapping,
    stale_after_from_event_timers,
)
from canopen_gateway.profiles.loader import (
    PROFILE_DIR,
    LoadedProfile,
    ProfileError,
    builtin_profiles,
    import_eds,
    load_profile,
    resolve_profile_path,
)
from canopen_gateway.profiles.node_profile import load_node_profile, resolve_eds_path
from canopen_gateway.profiles.node_setup import (
    ExternalHeartbeatSetup,
    NodeSetup,
    PdoSetup,
    SdoSetup,
)

__all__ = [
    "PROFILE_DIR",
    "STALE_EVENT_TIMER_MULTIPLE",
    "LoadedProfile",
    "ExternalHeartbeatSetup",
    "IdentityCheck",
    "NodeSetup",
    "PdoSetup",
    "SdoSetup",
    "ProfileError",
    "builtin_profiles",
    "device_supervision",
    "expected_identity",
    "identity_check",
    "import_eds",
    "load_node_profile",
    "load_profile",
    "node_verifies_mapping",
    "resolve_eds_path",
    "resolve_profile_path",
    "stale_after_from_event_timers",
]
