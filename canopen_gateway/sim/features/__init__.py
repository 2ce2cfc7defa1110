"""The simulator's device features (hooks of ``SimNode``, as ``bus.node.features`` are hooks of the
gateway's node): the hook API and the registry feature name -> class.

The simulator core (``canopen_gateway.sim.node.SimNode``) implements DS-301 for every device. What a
manual describes beyond DS-301 (LSS, a guarding bit, work areas, an Auto-ID procedure...) lives
in one module per *profile feature* under this package, as a subclass of :class:`SimFeature`
registered with :func:`register`. A node gets one instance of each feature class whose feature
appears in its profile's ``features:``; the feature's parameter dict (from the profile, updated
by the node's simulator options) is ``self.params``. Features are chosen by feature name, never by
device name.

Hooks are called by the node in this order for a frame: ``on_frame`` (may consume it), then the
core's handling (NMT / SYNC / SDO / RPDO / RTR), which calls the specific hooks below. Frames a
feature wants to send go through ``self.node.send(cob_id, data)``; values are read and written
with ``self.node.get(index, sub)`` / ``self.node.set(index, sub, value)`` (no access checks, no
hooks). All hooks get ``now`` (seconds, the caller's monotonic clock) and must be deterministic
given it: no wall clock, no sleeps, no threads.

What else a feature may use of its node: ``node_id``, ``nmt_state``, ``last_reset``,
``values.has(index, sub)``, ``default_of(index, sub)``, ``store`` (PersistentStore: node_id,
bitrate_index, values), ``pending_node_id`` and ``adopt_node_id_at_reset(node_id)`` (the id the
next reset communication adopts), ``raise_emcy(code, register, mfr, now=)`` /
``clear_emcy(code, now=)``, ``trigger_tpdo(n, now)``, ``set_nmt_state(state, now)``,
``reset_communication(now)``, ``mute(until_s)``, ``update_process(now)`` /
``invalidate_process()``, ``position_offset`` and ``set_position_offset(counts)``,
``direction_sign()``, ``calibrate(preset, now)``, ``motion``, ``hints`` (SimHints: ``position``
the position object; ``extra`` holds the profile's other ``sim:`` keys), ``feature(name)``.

Imports: python-can types and canopen_gateway.canopen.objref only (the node, sim.node, is referenced for
typing only).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any, ClassVar

import can

from canopen_gateway.canopen.objref import ObjRef

if TYPE_CHECKING:
    from canopen_gateway.sim.node import SimNode


class SimFeature:
    """Base class of a device feature: every hook does nothing by default.

    Subclasses set ``feature`` to the profile feature name they implement and override only the
    hooks they need.
    """

    feature: ClassVar[str] = ""

    def __init__(self, node: SimNode, params: dict[str, Any]) -> None:
        self.node = node
        self.params = params

    # -- lifecycle ---------------------------------------------------------------------------
    def on_boot(self, now: float) -> None:
        """After power-on, reset node or reset communication, just before the boot-up message.

        ``self.node.last_reset`` says which ("power", "node" or "communication"); object values
        have already been reloaded. A feature resets its own state here.
        """

    def on_nmt(self, state: int, now: float) -> None:
        """After the NMT state changed to ``state`` (4 stopped, 5 operational, 127 pre-op)."""

    # -- SDO server --------------------------------------------------------------------------
    def before_sdo_write(self, obj: ObjRef, value: Any, now: float) -> int | None:
        """A client writes ``value`` (decoded: int, str or bytes) to ``obj``.

        Called after the core's checks (existence, access, length, range). Return an SDO abort
        code to refuse the write, or None to let the core store it.
        """
        return None

    def after_sdo_write(self, obj: ObjRef, value: Any, now: float) -> None:
        """After an SDO download stored ``value`` in ``obj`` (RPDO writes call ``on_rpdo``)."""

    def before_sdo_read(self, obj: ObjRef, now: float) -> int | None:
        """A client reads ``obj`` (after ``update_process``). Return an abort code to refuse."""
        return None

    # -- process data ------------------------------------------------------------------------
    def on_rpdo(self, number: int, data: bytes, now: float) -> None:
        """After RPDO ``number`` (1-based) wrote its mapped objects from ``data``."""

    def on_sync(self, now: float) -> None:
        """A SYNC was received (before synchronous TPDOs are built)."""

    def update_process(self, now: float) -> None:
        """Compute process objects (status words, area states...) before a TPDO is built or a
        process object is read by SDO. The motion model has already updated position/velocity."""

    def tpdo_data(self, number: int, data: bytes, now: float) -> bytes:
        """The data TPDO ``number`` (1-based) carries: ``data`` is built from the mapping
        objects; return other bytes for a layout they do not describe (BEI POSI+ 2005h)."""
        return data

    # -- anything else -----------------------------------------------------------------------
    def on_frame(self, msg: can.Message, now: float) -> bool:
        """Every received frame, before the core sees it. Return True if consumed (e.g. LSS
        on 0x7E5); the core then ignores it."""
        return False

    def frame_cob_ids(self) -> Iterable[int] | None:
        """The 11-bit COB-IDs of the frames ``on_frame`` acts on, so that a runner can hand
        the node only those (see ``SimNode.listening``); None: every frame. Default: none when
        ``on_frame`` is not overridden, else every frame. Asked again whenever the node's
        node id or COB-ID objects change."""
        if type(self).on_frame is SimFeature.on_frame:
            return ()
        return None

    def tick(self, now: float) -> None:
        """Called on every node tick (about every millisecond under the runner)."""

    def on_fault(self, name: str, active: bool, now: float) -> bool:
        """A fault was injected or cleared (``sensor_error``, ``battery_low``,
        ``freeze_guarding_echo``...). Return True if this feature implements it."""
        return False


_REGISTRY: dict[str, type[SimFeature]] = {}


def register(cls: type[SimFeature]) -> type[SimFeature]:
    """Class decorator: make ``cls`` the simulation of profile feature ``cls.feature``."""
    if not cls.feature:
        raise ValueError(f"{cls.__name__} has no feature name")
    other = _REGISTRY.get(cls.feature)
    if other is not None and other is not cls:
        raise ValueError(f"feature {cls.feature!r} already implemented by {other.__name__}")
    _REGISTRY[cls.feature] = cls
    return cls


def feature_class(feature: str) -> type[SimFeature] | None:
    """The class simulating ``feature``, importing ``features/<feature>.py`` on first use;
    None if no module implements it (the core then simulates DS-301 only for that feature)."""
    if feature not in _REGISTRY:
        import importlib

        try:
            importlib.import_module(f"{__name__}.{feature}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{feature}":
                raise
            return None
    return _REGISTRY.get(feature)


def registered() -> dict[str, type[SimFeature]]:
    """Features with a class loaded so far (imports every module of this package first)."""
    import importlib
    import pkgutil

    for info in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{info.name}")
    return dict(_REGISTRY)
