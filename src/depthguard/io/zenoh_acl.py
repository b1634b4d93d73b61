"""Zenoh's access control for a cell's nodes: only the listed peers may publish distances and joint commands.

With one certificate per node (the cell file's ``tls_certificate = "certs/{node}.pem"``), every TLS link
carries the common name (CN) of the peer's certificate, checked by mutual TLS against the cell's CA. Each
node's Zenoh session then gets the ``access_control`` section built by :func:`access_control`:

* ``default_permission: deny``;
* ``graph``: anyone may declare subscribers, queryables and liveliness tokens and ask the graph (the
  ``@ros2_lv`` tokens that ``ros2 topic list`` and DepthGuard's own allow-list read), on every key;
* ``open``: anyone may put on the cell's other topics (images, joint states, task, status), on their exact
  rmw_zenoh key expressions, in both directions;
* ``protected_out``: a node may send the protected topics (distances and joint commands) to anyone;
* ``protected_in``: a node accepts them only from a peer whose certificate CN is one of ``publishers``.

A put that no rule allows is dropped by Zenoh before it reaches the application (Zenoh logs it only at its
``trace`` level); DepthGuard reports the unlisted publishers from the ROS graph instead
(:meth:`depthguard.io.zenoh_transport.ZenohNode.unlisted_publishers`). Deny wins over allow in Zenoh, so
the protected keys are never in an allow rule for everyone. The ACL identifies peers by certificate only:
the ROS 2 router's plain TCP link (``network.connect``) has no CN, so nothing that comes through it may
publish on the protected topics.
"""

from __future__ import annotations

import ssl
from pathlib import Path
from typing import Any

__all__ = ["GRAPH_MESSAGES", "access_control", "certificate_common_name"]

#: The message kinds of the ROS graph and of subscribing, allowed to everyone (Zenoh 1.x ACL names).
GRAPH_MESSAGES = [
    "declare_subscriber",
    "declare_queryable",
    "query",
    "reply",
    "liveliness_token",
    "liveliness_query",
    "declare_liveliness_subscriber",
]


def access_control(open_keys: list[str], protected_keys: list[str], publishers: list[str]) -> dict[str, Any]:
    """The ``access_control`` section of a node's Zenoh configuration.

    Args:
        open_keys: exact key expressions anyone may put on (the cell's other topics).
        protected_keys: exact key expressions that only ``publishers`` may put on (distances, commands).
        publishers: certificate common names allowed to publish on ``protected_keys`` (the cell file's
            ``network.publishers``, node names).
    """
    if not protected_keys:
        raise ValueError("access control needs at least one protected key expression")
    if not all(isinstance(p, str) and p for p in publishers):
        raise ValueError(f"publishers must be non-empty certificate common names, got {publishers!r}")
    overlap = set(open_keys) & set(protected_keys)
    if overlap:
        raise ValueError(f"a key cannot be both open and protected: {sorted(overlap)}")
    rules = [
        {"id": "graph", "permission": "allow", "flows": ["ingress", "egress"], "messages": GRAPH_MESSAGES,
         "key_exprs": ["**", "@ros2_lv/**"]},
        {"id": "protected_out", "permission": "allow", "flows": ["egress"], "messages": ["put"],
         "key_exprs": list(protected_keys)},
        {"id": "protected_in", "permission": "allow", "flows": ["ingress"], "messages": ["put"],
         "key_exprs": list(protected_keys)},
    ]  # fmt: skip
    anyone = ["graph", "protected_out"]
    if open_keys:
        rules.append(
            {"id": "open", "permission": "allow", "flows": ["ingress", "egress"], "messages": ["put"],
             "key_exprs": list(open_keys)}
        )  # fmt: skip
        anyone.append("open")
    policies = [{"id": "anyone", "rules": anyone, "subjects": ["anyone"]}]
    subjects: list[dict[str, Any]] = [{"id": "anyone"}]
    if publishers:
        subjects.append({"id": "publishers", "cert_common_names": sorted(set(publishers))})
        policies.append({"id": "publishers", "rules": ["protected_in"], "subjects": ["publishers"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def certificate_common_name(path: str | Path) -> str:
    """The common name (CN) of the subject of the PEM certificate at ``path``.

    Raises:
        ValueError: the file is not a PEM certificate or its subject has no common name.
    """
    try:
        # (the standard library's only certificate decoder; it has been there since Python 2.7)
        cert = ssl._ssl._test_decode_cert(str(path))  # type: ignore[attr-defined]  # noqa: SLF001
    except (OSError, ssl.SSLError) as exc:
        raise ValueError(f"{path}: not a readable PEM certificate ({exc})") from None
    for rdn in cert.get("subject", ()):
        for key, value in rdn:
            if key == "commonName":
                return str(value)
    raise ValueError(f"{path}: the certificate's subject has no common name (CN)")
