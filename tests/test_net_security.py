"""Zenoh TLS with mutual authentication between nodes (the cell file's tls_* keys): peers with a certificate
from the cell's CA talk; a peer with a certificate from another CA, or a plain TCP peer, gets no connection.
Certificates are made with the ``openssl`` command (skipped where it is missing)."""

from __future__ import annotations

import random
import shutil
import subprocess
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _certs(d: Path, name: str) -> tuple[Path, Path, Path]:
    def run(*args):
        subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True)

    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}-ca.key", "-out", f"{name}-ca.pem",
        "-days", "2", "-subj", f"/CN={name}-ca")  # fmt: skip
    run(
        "req",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-keyout",
        f"{name}.key",
        "-out",
        f"{name}.csr",
        "-subj",
        "/CN=localhost",
    )
    (d / "ext.cnf").write_text(
        "subjectAltName=IP:127.0.0.1,DNS:localhost\nbasicConstraints=CA:FALSE\n"
        "keyUsage=digitalSignature,keyEncipherment\nextendedKeyUsage=serverAuth,clientAuth\n"
    )
    run("x509", "-req", "-in", f"{name}.csr", "-CA", f"{name}-ca.pem", "-CAkey", f"{name}-ca.key",
        "-CAcreateserial", "-out", f"{name}.pem", "-days", "2", "-extfile", "ext.cnf")  # fmt: skip
    return d / f"{name}-ca.pem", d / f"{name}.pem", d / f"{name}.key"


@pytest.mark.slow
def test_mutual_tls_between_nodes(tmp_path):
    pytest.importorskip("zenoh")
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is needed to make test certificates")
    from depthguard.io import ros2
    from depthguard.io.cellfile import read_cell
    from depthguard.io.zenoh_transport import ZenohNode
    from depthguard.nodes.common import open_node

    ca, crt, key = _certs(tmp_path, "cell")
    oca, ocrt, okey = _certs(tmp_path, "other")
    base = random.randint(40000, 44000)
    text = (ROOT / "examples/cells/sim-hexagon.toml").read_text()
    text += f'\n[network]\nbase_port = {base}\nconnect = []\ntls_root_ca = "{ca}"\ntls_certificate = "{crt}"\n'
    text += f'tls_private_key = "{key}"\n'
    (tmp_path / "cell.toml").write_text(text)
    cell = read_cell(tmp_path / "cell.toml")
    dist = open_node(cell, "distance")  # listens on tls/127.0.0.1:base+3
    port = base + 3

    def tls(ca_, crt_, key_):
        return {
            "root_ca_certificate": str(ca_), "listen_certificate": str(crt_), "listen_private_key": str(key_),
            "connect_certificate": str(crt_), "connect_private_key": str(key_), "enable_mtls": True,
        }  # fmt: skip

    good = ZenohNode("controller", listen=[], connect=[f"tls/127.0.0.1:{port}"], tls=tls(ca, crt, key))
    stranger = ZenohNode("stranger", listen=[], connect=[f"tls/127.0.0.1:{port}"], tls=tls(oca, ocrt, okey))
    plain = ZenohNode("plain", listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    try:
        got = []
        good.subscribe("/depthguard/distances_test", "std_msgs/msg/String", lambda m, a, t: got.append(m.data),
                       check_order=False)  # fmt: skip
        pub = dist.publisher("/depthguard/distances_test", "std_msgs/msg/String")
        end = time.time() + 10
        while not got and time.time() < end:
            pub.publish(ros2.typestore().types["std_msgs/msg/String"](data="ok"))
            time.sleep(0.2)
        assert got, "TLS peers with the cell's certificates did not connect"
        assert list(stranger.session.info.peers_zid()) == [], "a certificate from another CA got in"
        assert list(plain.session.info.peers_zid()) == [], "a plain TCP peer got in"
    finally:
        for n in (good, stranger, plain, dist):
            n.close()
