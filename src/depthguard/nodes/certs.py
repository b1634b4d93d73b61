"""``depthguard certs``: a certificate authority and one certificate per node of a cell, for Zenoh's mutual TLS
and access control (docs/nodes.md, "One certificate per node").

Each node's certificate has the node's name as its common name (what Zenoh's access control matches) and the
cell's addresses as subject alternative names (what TLS checks when a node connects to another). The
``openssl`` command does the cryptography; an existing CA in the folder is reused (``ca.pem`` and
``ca.key``), so running the command again adds the certificates of new nodes without invalidating the others.
Private keys are written readable by their owner only.
"""

from __future__ import annotations

import ipaddress
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

from depthguard.io.cellfile import PER_NODE, node_names, read_cell

__all__ = ["make_cell_certificates"]


def _openssl(*args: str, cwd: Path) -> None:
    res = subprocess.run(["openssl", *args], cwd=cwd, capture_output=True, text=True)
    if res.returncode != 0:
        raise RuntimeError(f"openssl {args[0]} failed: {res.stderr.strip()[-500:]}")


def _san(hosts: list[str]) -> str:
    parts = []
    for h in hosts:
        try:
            ipaddress.ip_address(h)
            parts.append(f"IP:{h}")
        except ValueError:
            parts.append(f"DNS:{h}")
    return ",".join(dict.fromkeys(parts))


def _sign_node_certificate(out: Path, name: str, san: str, days: int) -> None:
    """``<name>.key`` and ``<name>.pem`` in ``out``: common name ``name``, alternative names ``san``, signed
    by ``out``'s CA for client and server use (mutual TLS)."""
    with tempfile.TemporaryDirectory() as tmp:
        ext, csr = Path(tmp) / "ext.cnf", Path(tmp) / f"{name}.csr"
        ext.write_text(
            f"subjectAltName={san}\nbasicConstraints=CA:FALSE\nkeyUsage=digitalSignature,keyEncipherment\n"
            "extendedKeyUsage=serverAuth,clientAuth\n"
        )
        _openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}.key", "-out", str(csr),
                 "-subj", f"/CN={name}", cwd=out)  # fmt: skip
        _openssl("x509", "-req", "-in", str(csr), "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
                 "-out", f"{name}.pem", "-days", str(days), "-extfile", str(ext), cwd=out)  # fmt: skip


def make_cell_certificates(
    cell_path: str | Path,
    out_dir: str | Path,
    *,
    days: int = 365,
    hosts: list[str] | None = None,
    nodes: list[str] | None = None,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Write ``ca.pem`` / ``ca.key`` (made, or reused when both exist) and ``<node>.pem`` / ``<node>.key`` for
    every node of the cell in ``out_dir``.

    Args:
        days: validity of new certificates, days.
        hosts: the addresses the nodes listen on (subject alternative names); default ``127.0.0.1``,
            ``localhost`` and the cell's ``network.host``.
        nodes: more node names (for example a ROS 2 node of yours that may publish distances).
        overwrite: replace existing node certificates (default: keep them).

    Returns ``{"folder", "ca", "made", "kept", "network"}``: ``network`` holds the cell file's ``[network]``
    lines that use the certificates (paths relative to the cell file where possible).

    Raises:
        RuntimeError: no ``openssl`` command, or a CA certificate without its key.
        ValueError: ``days`` not positive, or a node name that cannot be a file name.
    """
    if shutil.which("openssl") is None:
        raise RuntimeError("depthguard certs needs the openssl command (Debian: apt install openssl)")
    if int(days) <= 0:
        raise ValueError(f"days must be a positive number of days, got {days}")
    cell_path = Path(cell_path)
    cell = read_cell(cell_path)
    names = list(dict.fromkeys([*node_names(cell), *(nodes or [])]))
    for n in names:
        if not n or "/" in n or n.startswith(".") or n == "ca":
            raise ValueError(f"node name {n!r} cannot name a certificate file (no '/', no leading '.', not 'ca')")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    host = str((cell.network or {}).get("host", "127.0.0.1"))
    san = _san(list(hosts) if hosts else ["127.0.0.1", "localhost", host])
    ca, ca_key = out / "ca.pem", out / "ca.key"
    if ca.exists() != ca_key.exists():
        raise RuntimeError(f"{out}: ca.pem and ca.key go together; found only one of them")
    made, kept = [], []
    old_umask = os.umask(0o077)  # (private keys readable by their owner only)
    try:
        if not ca.exists():
            _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem",
                     "-days", str(int(days)), "-subj", f"/CN={cell.name}-ca", cwd=out)  # fmt: skip
            made.append("ca.pem")
        for n in names:
            if (out / f"{n}.pem").exists() and (out / f"{n}.key").exists() and not overwrite:
                kept.append(n)
            else:
                _sign_node_certificate(out, n, san, int(days))
                made.append(n)
    finally:
        os.umask(old_umask)
    for f in [ca, *(out / f"{n}.pem" for n in made if n != "ca.pem")]:
        f.chmod(0o644)  # (certificates are public; the keys stay 0600)
    try:
        rel = os.path.relpath(out.resolve(), cell_path.resolve().parent)
    except ValueError:  # (another drive)
        rel = str(out.resolve())
    network = [
        f'tls_root_ca = "{rel}/ca.pem"',
        f'tls_certificate = "{rel}/{PER_NODE}.pem"',
        f'tls_private_key = "{rel}/{PER_NODE}.key"',
    ]
    return {"folder": str(out.resolve()), "ca": str(ca.resolve()), "made": made, "kept": kept, "network": network}
