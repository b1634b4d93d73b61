"""The ``[network]`` table of a cell file (nodes on Zenoh, ``docs/nodes.md``) and the nodes' TLS files
(:mod:`depthguard.io.cellfile` reads the rest of the file and re-exports these names)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from depthguard.io.cell_schema import CellError, _section
from depthguard.validation import is_host

__all__ = ["PER_NODE", "ROUTER_PORT", "check_endpoint", "network_section", "per_node_certificates", "node_tls_files"]

#: In ``network.tls_certificate`` and ``tls_private_key``: the node's name (one certificate per node).
PER_NODE = "{node}"
#: The ROS 2 router's port (``rmw_zenohd``): no node may listen on it
ROUTER_PORT = 7447
_TLS = ("tls_root_ca", "tls_certificate", "tls_private_key")
#: Zenoh's locators ``PROTOCOL/ADDRESS`` (then ``?metadata`` and ``#config``); these take ``HOST:PORT``
_IP_PROTOCOLS = ("tcp", "tls", "udp", "quic", "ws")
_OTHER_PROTOCOLS = ("unixsock-stream", "unixpipe", "serial", "vsock")


def per_node_certificates(net: dict[str, Any]) -> bool:
    """Whether a (read) ``[network]`` table gives each node its own certificate (``{node}`` in the paths)."""
    return PER_NODE in net.get("tls_certificate", "")


def node_tls_files(net: dict[str, Any], name: str) -> tuple[str, str]:
    """Node ``name``'s certificate and private key paths from a (read) ``[network]`` table: the shared pair,
    or with ``{node}`` in the paths the node's own."""
    return net["tls_certificate"].replace(PER_NODE, name), net["tls_private_key"].replace(PER_NODE, name)


def check_endpoint(src: Path, key: str, endpoint: str) -> None:
    """A Zenoh endpoint ``PROTOCOL/HOST:PORT`` (``tcp/127.0.0.1:7447``; IPv6 hosts in brackets,
    ``tcp/[::1]:7447``; then optionally ``?metadata`` or ``#config``), or ``PROTOCOL/ADDRESS`` for Zenoh's other
    links (``unixsock-stream/PATH``); else :class:`CellError` naming ``key`` (e.g. ``network.connect[0]``)."""
    form = f'{src}: {key} must be a Zenoh endpoint such as "tcp/127.0.0.1:7447" (PROTOCOL/HOST:PORT), got'
    proto, _, address = endpoint.partition("/")
    address = re.split(r"[?#]", address, maxsplit=1)[0]
    if proto in _OTHER_PROTOCOLS and address.strip():
        return
    if proto not in _IP_PROTOCOLS:
        raise CellError(f"{form} {endpoint!r}: the protocol must be one of {list(_IP_PROTOCOLS + _OTHER_PROTOCOLS)}")
    host, sep, port = address.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1] if ":" in host else ""
    elif ":" in host:
        host = ""  # (an IPv6 address needs its brackets)
    if not sep or not is_host(host) or not port.isdecimal() or not 1 <= int(port) <= 65535:
        raise CellError(f"{form} {endpoint!r}")


def network_section(src: Path, table: Any, nodes: int = 8) -> dict[str, Any]:
    """The validated ``[network]`` table of cell file ``src`` (relative TLS paths made absolute); the cell has
    ``nodes`` nodes, on the ports ``base_port`` .. ``base_port + nodes - 1``."""
    net = _section(src, "network", "network", table)
    if not 0 <= net["domain"] <= 232:
        raise CellError(f"{src}: network.domain must be a ROS domain id in [0, 232], got {net['domain']}")
    last = net["base_port"] + nodes - 1
    if not 1024 <= net["base_port"] <= last <= 65535 or net["base_port"] <= ROUTER_PORT <= last:
        raise CellError(
            f"{src}: network.base_port must leave the cell's {nodes} node ports (base_port .. base_port + {nodes - 1})"
            f" in [1024, 65535] and off the ROS 2 router's port {ROUTER_PORT}, got {net['base_port']}"
        )
    for key in ("connect", "publishers"):
        if not all(isinstance(x, str) and x for x in net[key]):
            raise CellError(f"{src}: network.{key} must be an array of non-empty strings, got {net[key]!r}")
    for i, endpoint in enumerate(net["connect"]):
        check_endpoint(src, f"network.connect[{i}]", endpoint)
    if not is_host(net["host"]):
        raise CellError(
            f"{src}: network.host must be an IP address or a host name (the nodes listen on it), got {net['host']!r}"
        )
    tls = [net[k] for k in _TLS]
    if any(tls) and not all(tls):  # (a root CA alone would leave plain TCP; a pair without a CA cannot be checked)
        missing = [k for k in _TLS if not net[k]]
        raise CellError(f"{src}: network.{', '.join(missing)} missing: Zenoh TLS takes {', '.join(_TLS)} all, or none")
    if net["host"] not in ("127.0.0.1", "localhost", "::1") and not all(tls):
        raise CellError(
            f"{src}: network.host {net['host']!r} is not loopback: give tls_root_ca, tls_certificate and"
            " tls_private_key (Zenoh TLS) to open a network endpoint"
        )
    per_node = [PER_NODE in net[k] for k in ("tls_certificate", "tls_private_key")]
    if PER_NODE in net["tls_root_ca"] or per_node[0] != per_node[1]:
        raise CellError(
            f"{src}: network.tls_certificate and tls_private_key take {{node}} (one certificate per node)"
            " both or neither, and tls_root_ca never"
        )
    for k in _TLS:
        if net[k]:
            path = (src.parent / net[k]).resolve()
            if PER_NODE in net[k]:  # (each node's own file is checked when the node starts)
                if PER_NODE not in str(path.parent) and not path.parent.is_dir():
                    raise CellError(f"{src}: network.{k} '{net[k]}': no folder {path.parent}")
            elif not path.is_file():
                raise CellError(f"{src}: network.{k} '{net[k]}' is not a file (looked at {path})")
            net[k] = str(path)
    return net
