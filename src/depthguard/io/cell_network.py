"""The ``[network]`` table of a cell file (nodes on Zenoh, ``docs/nodes.md``) and the nodes' TLS files
(:mod:`depthguard.io.cellfile` reads the rest of the file and re-exports these names)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from depthguard.io.cell_schema import CellError, _section

__all__ = ["PER_NODE", "network_section", "per_node_certificates", "node_tls_files"]

#: In ``network.tls_certificate`` and ``tls_private_key``: the node's name (one certificate per node).
PER_NODE = "{node}"


def per_node_certificates(net: dict[str, Any]) -> bool:
    """Whether a (read) ``[network]`` table gives each node its own certificate (``{node}`` in the paths)."""
    return PER_NODE in net.get("tls_certificate", "")


def node_tls_files(net: dict[str, Any], name: str) -> tuple[str, str]:
    """Node ``name``'s certificate and private key paths from a (read) ``[network]`` table: the shared pair,
    or with ``{node}`` in the paths the node's own."""
    return net["tls_certificate"].replace(PER_NODE, name), net["tls_private_key"].replace(PER_NODE, name)


def network_section(src: Path, table: Any) -> dict[str, Any]:
    """The validated ``[network]`` table of cell file ``src`` (relative TLS paths made absolute)."""
    net = _section(src, "network", "network", table)
    if not 0 <= net["domain"] <= 232:
        raise CellError(f"{src}: network.domain must be a ROS domain id in [0, 232], got {net['domain']}")
    if not 1024 <= net["base_port"] <= 65000 or net["base_port"] == 7447:
        raise CellError(f"{src}: network.base_port must be in [1024, 65000] and not 7447, got {net['base_port']}")
    for key in ("connect", "publishers"):
        if not all(isinstance(x, str) and x for x in net[key]):
            raise CellError(f"{src}: network.{key} must be an array of non-empty strings")
    tls = [net[k] for k in ("tls_root_ca", "tls_certificate", "tls_private_key")]
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
    for k in ("tls_root_ca", "tls_certificate", "tls_private_key"):
        if net[k]:
            path = (src.parent / net[k]).resolve()
            if PER_NODE in net[k]:  # (each node's own file is checked when the node starts)
                if PER_NODE not in str(path.parent) and not path.parent.is_dir():
                    raise CellError(f"{src}: network.{k} '{net[k]}': no folder {path.parent}")
            elif not path.is_file():
                raise CellError(f"{src}: network.{k} '{net[k]}' is not a file (looked at {path})")
            net[k] = str(path)
    return net
