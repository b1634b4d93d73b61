"""Test certificates made with the ``openssl`` command: one CA and certificates it signs, each for 127.0.0.1
and localhost, usable by a TLS server and client alike (Zenoh's mutual TLS)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

_EXT = (
    "subjectAltName=IP:127.0.0.1,DNS:localhost\nbasicConstraints=CA:FALSE\n"
    "keyUsage=digitalSignature,keyEncipherment\nextendedKeyUsage=serverAuth,clientAuth\n"
)


def need_openssl() -> None:
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is needed to make test certificates")


def make_ca(d: Path, name: str) -> tuple[Path, Path]:
    """A self-signed CA ``<name>-ca.pem`` with its key, in ``d``."""
    _openssl(d, "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}-ca.key", "-out",
             f"{name}-ca.pem", "-days", "2", "-subj", f"/CN={name}-ca")  # fmt: skip
    return d / f"{name}-ca.pem", d / f"{name}-ca.key"


def make_cert(d: Path, ca: tuple[Path, Path], file_stem: str, common_name: str) -> tuple[Path, Path]:
    """``<file_stem>.pem`` and ``.key`` in ``d``: a certificate with common name ``common_name`` signed by
    ``ca`` (its certificate and key)."""
    _openssl(d, "req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{file_stem}.key", "-out", f"{file_stem}.csr",
             "-subj", f"/CN={common_name}")  # fmt: skip
    (d / "ext.cnf").write_text(_EXT)
    _openssl(d, "x509", "-req", "-in", f"{file_stem}.csr", "-CA", str(ca[0]), "-CAkey", str(ca[1]),
             "-CAcreateserial", "-out", f"{file_stem}.pem", "-days", "2", "-extfile", "ext.cnf")  # fmt: skip
    return d / f"{file_stem}.pem", d / f"{file_stem}.key"


def tls_settings(ca: Path, crt: Path, key: Path) -> dict[str, object]:
    """Zenoh's ``transport/link/tls`` settings for mutual TLS with these files."""
    return {
        "root_ca_certificate": str(ca), "listen_certificate": str(crt), "listen_private_key": str(key),
        "connect_certificate": str(crt), "connect_private_key": str(key), "enable_mtls": True,
    }  # fmt: skip


def _openssl(d: Path, *args: str) -> None:
    subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True)
