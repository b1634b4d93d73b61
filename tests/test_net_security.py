"""Zenoh TLS with mutual authentication between nodes (the cell file's tls_* keys): peers with a certificate
from the cell's CA talk; a peer with a certificate from another CA, or a plain TCP peer, gets no connection.
Certificates are made with the ``openssl`` command (skipped where it is missing)."""

from __future__ import annotations

import random
import time
from pathlib import Path

import pytest

from certs import make_ca, make_cert, need_openssl, tls_settings

ROOT = Path(__file__).resolve().parents[1]


def _certs(d: Path, name: str) -> tuple[Path, Path, Path]:
    ca = make_ca(d, name)
    crt, key = make_cert(d, ca, name, "localhost")
    return ca[0], crt, key


@pytest.mark.slow
def test_mutual_tls_between_nodes(tmp_path):
    pytest.importorskip("zenoh")
    need_openssl()
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

    good = ZenohNode("controller", listen=[], connect=[f"tls/127.0.0.1:{port}"], tls=tls_settings(ca, crt, key))
    stranger = ZenohNode("stranger", listen=[], connect=[f"tls/127.0.0.1:{port}"], tls=tls_settings(oca, ocrt, okey))
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
