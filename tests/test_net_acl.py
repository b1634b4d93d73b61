"""Zenoh's access control with one certificate per node (``tls_certificate = "certs/{node}.pem"``).

The ACL section that every node gets lets only the certificates named in ``network.publishers`` put on the
distances and joint-command keys; the ROS graph and the other topics stay open to the cell's peers. The slow
test runs real Zenoh sessions over mutual TLS: an impostor that gives its node the listed name
``distance`` but holds another certificate gets through DepthGuard's own allow-list (which trusts the
graph's names), and Zenoh's ACL drops it; the controller reports it from the graph.
"""

from __future__ import annotations

import json
import random
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from certs import make_ca, make_cert, need_openssl, tls_settings
from depthguard.io.cellfile import CellError, read_cell
from depthguard.io.rmw_zenoh import topic_keyexpr
from depthguard.io.zenoh_acl import access_control, certificate_common_name
from depthguard.nodes.common import Topics, node_access_control, node_certificate, node_names

ROOT = Path(__file__).resolve().parents[1]
CELL = ROOT / "examples/cells/sim-hexagon.toml"
DIST = "depthguard_msgs/msg/ControlPointDistances"


def _cell(d: Path, network: str) -> Path:
    p = d / "cell.toml"
    p.write_text(CELL.read_text() + "\n[network]\n" + network)
    return p


def _per_node(d: Path, base: int = 7460, publishers: str = "") -> str:
    return (
        f'base_port = {base}\nconnect = []\ntls_root_ca = "{d}/cell-ca.pem"\n'
        f'tls_certificate = "{d}/{{node}}.pem"\ntls_private_key = "{d}/{{node}}.key"\n{publishers}'
    )


def _allowed_puts(acl: dict, flow: str) -> dict[str, set]:
    """key -> the subjects (ids) for which some allow rule lets a ``put`` through in ``flow``."""
    subjects = {s["id"]: s for s in acl["subjects"]}
    out: dict[str, set] = {}
    for pol in acl["policies"]:
        for rid in pol["rules"]:
            rule = next(r for r in acl["rules"] if r["id"] == rid)
            if rule["permission"] == "allow" and "put" in rule["messages"] and flow in rule["flows"]:
                for k in rule["key_exprs"]:
                    out.setdefault(k, set()).update(subjects[s]["id"] for s in pol["subjects"])
    return out


def test_acl_section_lets_only_the_listed_certificates_put_distances_and_commands(tmp_path):
    (tmp_path / "cell-ca.pem").write_text("(a CA)")
    cell = read_cell(_cell(tmp_path, _per_node(tmp_path, publishers='publishers = ["distance", "ctl2"]\n')))
    acl = node_access_control(cell, 3)
    assert acl["enabled"] and acl["default_permission"] == "deny"
    assert not any(r["permission"] == "deny" for r in acl["rules"])  # (a deny would beat every allow)
    open_, protected = Topics.of(cell).typed()
    p_keys = {topic_keyexpr(3, t, ty) for t, ty in protected}
    o_keys = {topic_keyexpr(3, t, ty) for t, ty in open_}
    assert len(p_keys) == 5 and topic_keyexpr(3, cell.topics["distances"], DIST) in p_keys
    assert topic_keyexpr(3, "/depthguard/joint_command", "sensor_msgs/msg/JointState") in p_keys
    ingress, egress = _allowed_puts(acl, "ingress"), _allowed_puts(acl, "egress")
    subjects = {s["id"]: s for s in acl["subjects"]}
    for k in p_keys:  # in: only subjects that name certificates, and only the listed ones
        assert ingress[k] and all(subjects[s].get("cert_common_names") for s in ingress[k])
        assert set().union(*(subjects[s]["cert_common_names"] for s in ingress[k])) == {"distance", "ctl2"}
        assert egress[k] == {"anyone"} and subjects["anyone"] == {"id": "anyone"}  # out: to anyone
    for k in o_keys:  # every other topic of the cell: anyone, both ways
        assert ingress[k] == egress[k] == {"anyone"}
    assert set(ingress) == p_keys | o_keys  # nothing else may be put
    graph = next(r for r in acl["rules"] if r["id"] == "graph")
    assert "put" not in graph["messages"] and "@ros2_lv/**" in graph["key_exprs"]


def test_acl_section_refuses_what_it_cannot_mean():
    with pytest.raises(ValueError, match="both open and protected"):
        access_control(["0/a/T/RIHS01_x"], ["0/a/T/RIHS01_x"], ["distance"])
    with pytest.raises(ValueError, match="at least one protected"):
        access_control(["0/a/T/RIHS01_x"], [], ["distance"])
    with pytest.raises(ValueError, match="certificate common names"):
        access_control([], ["0/d/T/RIHS01_x"], ["distance", ""])
    nobody = access_control([], ["0/d/T/RIHS01_x"], [])  # no publishers: nobody may send them in
    assert _allowed_puts(nobody, "ingress") == {}


def test_cell_file_takes_node_placeholders_in_both_paths_or_neither(tmp_path):
    for bad in (
        f'tls_root_ca = "{tmp_path}/ca.pem"\ntls_certificate = "{tmp_path}/{{node}}.pem"\n'
        f'tls_private_key = "{tmp_path}/k.key"\n',
        f'tls_root_ca = "{tmp_path}/{{node}}.pem"\ntls_certificate = "{tmp_path}/{{node}}.pem"\n'
        f'tls_private_key = "{tmp_path}/{{node}}.key"\n',
    ):
        (tmp_path / "ca.pem").write_text("x")
        (tmp_path / "k.key").write_text("x")
        with pytest.raises(CellError, match=r"take \{node\}"):
            read_cell(_cell(tmp_path, bad))
    net = _per_node(tmp_path).replace(f'"{tmp_path}/{{node}}.pem"', f'"{tmp_path}/missing/{{node}}.pem"')
    (tmp_path / "cell-ca.pem").write_text("(a CA)")
    with pytest.raises(CellError, match="no folder"):
        read_cell(_cell(tmp_path, net))


def test_cell_check_says_how_the_nodes_are_secured(tmp_path):
    from depthguard.io.cell_describe import describe_cell

    assert "plain TCP (no TLS)" in describe_cell(read_cell(CELL))
    (tmp_path / "cell-ca.pem").write_text("(a CA)")
    for n in ("sim", "distance"):
        (tmp_path / f"{n}.pem").write_text("(a certificate)")
    text = describe_cell(read_cell(_cell(tmp_path, _per_node(tmp_path, 47000))))
    line = next(x for x in text.splitlines() if x.startswith("network:"))
    assert "ports 47000-47007" in line and "one certificate per node, Zenoh's access control on" in line
    assert "no certificate yet for: camera0, camera1, controller, monitor, run, view" in line


def test_node_certificate_must_name_its_node(tmp_path):
    need_openssl()
    ca = make_ca(tmp_path, "cell")
    make_cert(tmp_path, ca, "distance", "distance")
    make_cert(tmp_path, ca, "controller", "distance")  # the controller's file, the distance node's name
    net = read_cell(_cell(tmp_path, _per_node(tmp_path))).network
    assert certificate_common_name(tmp_path / "distance.pem") == "distance"
    assert node_certificate(net, "distance") == (str(tmp_path / "distance.pem"), str(tmp_path / "distance.key"))
    with pytest.raises(ValueError, match=r"common name 'distance'.*node's name 'controller'"):
        node_certificate(net, "controller")
    with pytest.raises(ValueError, match="node 'monitor' has no file"):
        node_certificate(net, "monitor")
    with pytest.raises(ValueError, match="not a readable PEM certificate"):
        certificate_common_name(tmp_path / "ext.cnf")


def test_node_with_acl_refuses_a_topic_outside_it(tmp_path):
    pytest.importorskip("zenoh")
    from depthguard.io.zenoh_transport import ZenohNode

    cell = read_cell(CELL)
    node = ZenohNode("distance", listen=[], connect=[], access_control=node_access_control(cell, 0))
    try:
        node.publisher(cell.topics["distances"], DIST)  # in the ACL: fine
        with pytest.raises(ValueError, match="not in this node's access control"):
            node.publisher("/elsewhere", "std_msgs/msg/String")
        with pytest.raises(ValueError, match="not in this node's access control"):
            node.subscribe(cell.topics["distances"], "std_msgs/msg/String", lambda *a: None)
    finally:
        node.close()


@pytest.mark.slow
def test_acl_drops_an_impostor_that_the_name_allow_list_lets_through(tmp_path):
    """Real Zenoh sessions over mutual TLS, every certificate from the cell's CA. The controller and the
    distance node are the cell's (per-node certificates, ACL on); the impostor calls its node ``distance``
    with the certificate of ``stranger``; a witness without ACL applies only DepthGuard's name allow-list."""
    pytest.importorskip("zenoh")
    need_openssl()
    from depthguard.io import ros2
    from depthguard.io.zenoh_transport import ZenohNode
    from depthguard.nodes.common import _endpoint, open_node

    ca = make_ca(tmp_path, "cell")
    for n in ("distance", "controller", "stranger", "monitor"):
        make_cert(tmp_path, ca, n, n)
    base = random.randint(44000, 48000)
    cell = read_cell(_cell(tmp_path, _per_node(tmp_path, base)))
    top = Topics.of(cell)
    ctl, dist = open_node(cell, "controller"), open_node(cell, "distance")
    wit_ep = _endpoint(cell, base + node_names(cell).index("monitor"))
    w_tls = tls_settings(ca[0], tmp_path / "monitor.pem", tmp_path / "monitor.key")
    witness = ZenohNode("monitor", listen=[wit_ep], connect=[], tls=w_tls)
    targets = [_endpoint(cell, base + node_names(cell).index("controller")), wit_ep]
    s_tls = tls_settings(ca[0], tmp_path / "stranger.pem", tmp_path / "stranger.key")
    impostor = ZenohNode("distance", listen=[], connect=targets, tls=s_tls)
    stranger = ZenohNode("stranger", listen=[], connect=targets, tls=s_tls)
    got: dict[str, list] = {"ctl": [], "wit": [], "js": []}
    try:
        sub = ctl.subscribe(top.distances, DIST, lambda m, a, t: got["ctl"].append(float(m.points[0].distance)),
                            allowed={"distance"}, check_order=False)  # fmt: skip
        wsub = witness.subscribe(top.distances, DIST, lambda m, a, t: got["wit"].append(float(m.points[0].distance)),
                                 allowed={"distance"}, check_order=False)  # fmt: skip
        ctl.subscribe(top.joint_states, "sensor_msgs/msg/JointState", lambda m, a, t: got["js"].append(1),
                      check_order=False)  # fmt: skip
        senders = [
            (n.publisher(top.distances, DIST), tag) for n, tag in ((dist, 1.0), (impostor, 2.0), (stranger, 3.0))
        ]
        js = stranger.publisher(top.joint_states, "sensor_msgs/msg/JointState")  # an open topic
        end = time.time() + 15
        while time.time() < end and not (1.0 in got["ctl"] and 2.0 in got["wit"] and got["js"]):
            for pub, tag in senders:
                pub.publish(ros2.distances_msg(time.time(), ["ee"], np.zeros((1, 3)), [0.1], [tag], [[1.0, 0, 0]]))
            js.publish(ros2.joint_state_msg(time.time(), ["j"], [0.0]))
            time.sleep(0.1)
        time.sleep(0.3)
        assert 1.0 in got["ctl"], "the listed distance node's samples did not reach the controller"
        assert got["js"], "an open topic from a peer of the cell's CA was dropped"
        assert 2.0 in got["wit"], "the witness (name allow-list only) should have taken the impostor's samples"
        assert 3.0 not in got["wit"] and "stranger" in wsub.rejected_publishers
        assert set(got["ctl"]) == {1.0}, "Zenoh's ACL let an unlisted certificate publish distances"
        assert "publisher not allowed" not in sub.dropped  # (dropped by Zenoh, never seen here)
        assert sub.unlisted_publishers == {"stranger", "distance (certificate stranger)"}
        assert wsub.unlisted_publishers == {"stranger"}  # (without ACL the names are all there is)
    finally:
        for n in (impostor, stranger, witness, dist, ctl):
            n.close()


@pytest.mark.slow
def test_every_node_starts_under_access_control(tmp_path):
    """Each of the cell's nodes (``sim``, both cameras, ``distance``, ``controller``, ``monitor``, the
    ``run`` publisher, ``view``) starts with its own certificate and Zenoh's access control and runs briefly:
    a node that declared a topic outside its access control would refuse to start (Zenoh would drop it)."""
    pytest.importorskip("zenoh")
    pytest.importorskip("viser")
    need_openssl()
    from depthguard.nodes import run_node
    from depthguard.nodes.runpub import ZenohRunPublisher
    from depthguard.viz.live_node import run_view_node

    ca = make_ca(tmp_path, "cell")
    cell_path = _cell(tmp_path, _per_node(tmp_path, random.randint(48000, 52000)))
    cell = read_cell(cell_path)
    for n in node_names(cell):
        make_cert(tmp_path, ca, n, n)
    ran = {}
    for n in ("sim", "camera0", "camera1", "distance", "controller", "monitor"):
        src = {"source": "sim:ral-hexagon", "quick": True} if n == "sim" else {}
        ran[n] = run_node(n, str(cell_path), duration=0.3, **src)
    ran["run"] = ZenohRunPublisher(cell, chain=None).close()
    ran["view"] = run_view_node(str(cell_path), port=random.randint(52001, 56000), duration=0.3)
    assert set(ran) == set(node_names(cell))


@pytest.mark.slow
def test_certs_command_makes_what_every_node_needs(tmp_path, capsys):
    """``depthguard certs``: a CA and one certificate per node whose common name is the node's name; with
    the [network] lines it prints, two nodes of the cell talk over mutual TLS under access control."""
    pytest.importorskip("zenoh")
    need_openssl()
    from depthguard.cli import main
    from depthguard.io import ros2
    from depthguard.nodes.common import open_node

    cell_path = _cell(tmp_path, f"base_port = {random.randint(56001, 60000)}\nconnect = []\n")
    text = cell_path.read_text()
    assert main(["certs", "--cell", str(cell_path), "--out", str(tmp_path / "certs"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    cell_path.write_text(text + "\n".join(out["network"]) + "\n")
    cell = read_cell(cell_path)
    assert set(out["made"]) == {"ca.pem", *node_names(cell)} and out["kept"] == []
    for n in node_names(cell):
        assert node_certificate(cell.network, n)[0].endswith(f"certs/{n}.pem")  # (its CN is its name)
        assert (tmp_path / "certs" / f"{n}.key").stat().st_mode & 0o077 == 0, "a private key others can read"
    assert main(["certs", "--cell", str(cell_path), "--out", str(tmp_path / "certs"), "--node", "extra", "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["made"] == ["extra"] and set(again["kept"]) == set(node_names(cell))  # (the CA reused)
    ctl, dist = open_node(cell, "controller"), open_node(cell, "distance")
    got = []
    try:
        ctl.subscribe(cell.topics["distances"], DIST, lambda m, a, t: got.append(1), allowed={"distance"})
        pub = dist.publisher(cell.topics["distances"], DIST)
        end = time.time() + 10
        while not got and time.time() < end:
            pub.publish(ros2.distances_msg(time.time(), ["ee"], np.zeros((1, 3)), [0.1], [0.5], [[1.0, 0, 0]]))
            time.sleep(0.1)
        assert got, "nodes with the certificates of depthguard certs did not talk"
    finally:
        ctl.close()
        dist.close()


_KEY = st.from_regex(r"[0-9]{1,3}/[a-z_]{1,8}(/[a-z_]{1,8}){0,2}/[A-Za-z_:]{1,12}/RIHS01_[0-9a-f]{6}", fullmatch=True)


@given(
    open_keys=st.lists(_KEY, max_size=6, unique=True),
    protected=st.lists(_KEY, min_size=1, max_size=6, unique=True),
    publishers=st.lists(st.from_regex(r"[a-z][a-z0-9_]{0,10}", fullmatch=True), max_size=4),
)
def test_acl_section_invariants_hold_for_any_topics_and_publishers(open_keys, protected, publishers):
    """For any open and protected keys and any publishers: default deny, no deny rule, every protected key
    comes in only from the listed certificates and goes out to anyone, every open key both ways for anyone,
    nothing else may be put, and the graph stays open."""
    open_keys = [k for k in open_keys if k not in protected]
    acl = access_control(open_keys, protected, publishers)
    assert acl["enabled"] and acl["default_permission"] == "deny"
    assert all(r["permission"] == "allow" for r in acl["rules"])
    ingress, egress = _allowed_puts(acl, "ingress"), _allowed_puts(acl, "egress")
    subjects = {s["id"]: s for s in acl["subjects"]}
    for k in protected:
        names = set().union(*(subjects[s].get("cert_common_names", {"*"}) for s in ingress.get(k, set())))
        assert names == set(publishers), (k, names)
        assert egress[k] == {"anyone"}
    for k in open_keys:
        assert ingress[k] == egress[k] == {"anyone"}
    assert set(ingress) == set(open_keys) | (set(protected) if publishers else set())
    graph = [r for r in acl["rules"] if "put" not in r["messages"]]
    assert graph and all("@ros2_lv/**" in r["key_exprs"] and "**" in r["key_exprs"] for r in graph)


@pytest.mark.slow
def test_the_whole_chain_moves_the_arm_under_access_control(tmp_path):
    """Real processes (``sim``, both cameras, ``distance``, ``controller``), each with its own certificate and
    Zenoh's access control: the frames, masks, joint states, distances and joint commands all get through,
    so the controller moves the arm (a subscriber with the ``monitor`` certificate watches its status) and the
    driver takes its commands (its watchdog does not hold the arm); the controller's final report lists no
    unlisted publisher and no refused message."""
    pytest.importorskip("zenoh")
    pytest.importorskip("mujoco")
    need_openssl()
    from certs import tls_settings
    from test_nodes_faults import MOVING, StatusWatch, System

    ca = make_ca(tmp_path, "cell")
    network = (
        f'tls_root_ca = "{ca[0]}"\ntls_certificate = "{tmp_path}/{{node}}.pem"\n'
        f'tls_private_key = "{tmp_path}/{{node}}.key"\n'
    )
    sysm = System(tmp_path, network)
    for n in node_names(read_cell(sysm.cell)):
        make_cert(tmp_path, ca, n, n)
    watch = None
    try:
        for n in ("sim", "camera0", "camera1", "distance", "controller"):
            sysm.start(n)
        tls = tls_settings(ca[0], tmp_path / "monitor.pem", tmp_path / "monitor.key")
        watch = StatusWatch(sysm.cell, name="monitor", tls=tls)
        t_ok = watch.wait_for(MOVING, 0.0, 120.0)
        assert t_ok, f"never moved; statuses: {sorted({s for _, s in watch.events})}"
        time.sleep(1.5)
        js = [json.loads(x) for x in (tmp_path / "sim.log").read_text().splitlines() if '"js"' in x]
        driven = [r for r in js if r["t"] > t_ok + 0.5 and not r["held"]]
        assert driven, "the driver never took a joint command (its watchdog held the arm)"
        sysm.stop("controller")
        out = [json.loads(x) for x in (tmp_path / "controller.out").read_text().splitlines() if x.startswith("{")]
        assert out[-1]["unlisted_publishers"] == [] and out[-1]["rejected_publishers"] == []
        assert not any("refused" in k for d in out[-1]["dropped_by_topic"].values() for k in d), out[-1]
    finally:
        if watch is not None:
            watch.close()
        sysm.close()
