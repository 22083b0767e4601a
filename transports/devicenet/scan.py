"""Finding the DeviceNet nodes on a bus: the MAC ids that answer, their identity objects and their models.

The scan is the monitoring path of the transport, one MAC id at a time: the explicit messaging connection is
allocated (Allocate choice 0x01, never the polled I/O connection: no output data, so no run bit, reaches any
node; docs/devicenet.md, "Reading never takes control"), the identity object's attributes 1-7 are read with
Get_Attribute_Single, and the connection is released. A MAC id that does not answer the allocation within
the timeout is nobody. One scanner (the bus's duplicate MAC id check done once) serves the whole scan.

A node's model is the installed model whose DeviceNet identity (``[transports.devicenet] identity``: vendor
id, product code, product name) the node reports; none fits: unknown.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from starterbus.core import DeviceUrl, Profile, StarterbusError, TimeoutError
from starterbus.transports.devicenet.settings import profile_identity
from starterbus.transports.devicenet.transport import SCANNERS, DeviceNetTransport
from starterbus.transports.devicenet.url import NAME

Progress = Callable[[str], None]
#: what must agree between a node's identity and a model's for the node to be that model
MATCHED = ("vendor_id", "product_code", "product_name")


@dataclass(frozen=True, slots=True)
class Node:
    """A MAC id that answered: its identity object (attribute names as ``identify`` prints them) and model."""

    mac: int
    identity: dict[str, object]
    model: str | None
    why: str


def model_of(identity: dict[str, object], profiles: Sequence[Profile]) -> tuple[str | None, str]:
    """The model whose DeviceNet identity the node reports, and why (or why none)."""
    for profile in profiles:
        expected = profile_identity(profile).as_dict()
        if all(identity.get(name) == expected.get(name) for name in MATCHED):
            return profile.name, f"its identity is {profile.display_name}'s (vendor, product code, name)"
    shown = ", ".join(f"{name} {identity.get(name)!r}" for name in MATCHED)
    return None, f"no installed model has this identity ({shown})"


def node_url(url: DeviceUrl, mac: int, timeout: float) -> DeviceUrl:
    """``url`` (its query kept: master_mac, bitrate, dup_mac_wait) for one MAC id, monitoring only."""
    base, _, query = url.text.partition("?")
    kept = [p for p in query.split("&") if p and p.partition("=")[0] not in ("mac", "timeout", "control")]
    return DeviceUrl.parse(f"{base}?{'&'.join([*kept, f'mac={mac}', f'timeout={timeout:g}', 'control=command'])}")


def scan_bus(
    url: DeviceUrl,
    profiles: Sequence[Profile],
    macs: Sequence[int],
    *,
    timeout: float = 0.2,
    progress: Progress = lambda _: None,
) -> list[Node]:
    """Every MAC id of ``macs`` that answers on the bus of ``url`` (``devicenet://INTERFACE/CHANNEL``), with its
    identity; ``profiles`` (those with a DeviceNet interface) tell the models. Reads only."""
    if url.transport != NAME:
        raise StarterbusError(f"{url.text}: not a DeviceNet bus")
    first = DeviceNetTransport(node_url(url, macs[0], timeout), profiles[0])
    key = (first.scanner_config.interface, first.scanner_config.channel)
    from starterbus.transports.devicenet.driver.scanner import Scanner

    config = first.scanner_config
    SCANNERS.acquire(key, lambda: Scanner(config))  # one scanner (one duplicate MAC check) for the whole scan
    found: list[Node] = []
    try:
        for mac in macs:
            if mac == config.master_mac:
                continue
            progress(f"scan: MAC {mac}")
            transport = DeviceNetTransport(node_url(url, mac, timeout), profiles[0])
            try:
                with transport:
                    identity = transport.identify()
            except TimeoutError:
                continue
            identity.pop("mac", None)
            for private in ("input_assembly", "output_assembly", "io_connection", "expected_packet_rate_ms"):
                identity.pop(private, None)
            model, why = model_of(identity, profiles)
            progress(f"scan: MAC {mac}: {model or 'model unknown'} ({why})")
            found.append(Node(mac, identity, model, why))
    finally:
        SCANNERS.release(key)
    return found
