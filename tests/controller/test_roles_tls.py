"""The deployment config over Zenoh's TLS transport, as README's "TLS" steps set it up: a farm CA
and a controller certificate made with openssl, the router listening on tls/..., tools trusting
the CA with --ca. Passwords then travel encrypted; everything else is as over tcp/."""
from __future__ import annotations

import json
import os
import shutil
import subprocess

import pytest

from tests.controller.zenoh_farm import FISHFARM, start_farm

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not installed")


def _openssl(*args: str, cwd) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


def make_certificates(tmp) -> None:
    """README's commands: the farm's CA, and the controller's certificate for localhost/127.0.0.1."""
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes"]
    _openssl("req", "-x509", *ec, "-keyout", "ca.key", "-out", "ca.pem", "-days", "3650",
             "-subj", "/CN=fishfarm farm CA", cwd=tmp)
    _openssl("req", *ec, "-keyout", "controller.key", "-out", "controller.csr", "-subj", "/CN=controller", cwd=tmp)
    (tmp / "san.cnf").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    _openssl("x509", "-req", "-in", "controller.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
             "-out", "controller.pem", "-days", "825", "-extfile", "san.cnf", cwd=tmp)


@pytest.fixture(scope="module")
def farm(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tls")
    make_certificates(tmp)
    farm, stop = start_farm(tmp, scheme="tls", tls={"listen_certificate": str(tmp / "controller.pem"),
                                                    "listen_private_key": str(tmp / "controller.key")})
    farm.ca = str(tmp / "ca.pem")
    yield farm
    stop()


def _fishfarm(*args):
    return subprocess.run([FISHFARM, *args], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "USER": "tester"})


def test_tools_reach_the_controller_over_tls_with_the_farm_ca(farm):
    port = farm.endpoint.rsplit(":", 1)[1]
    ana = ["--user", "ana", "--password", farm.passwords["ana"], "--ca", farm.ca]
    farm.calls.clear()
    proc = _fishfarm("override", "feed", "tank=T1", "grams=5", "--connect", f"tls/localhost:{port}", *ana)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == {"ok": True, "command": "feed"}
    assert farm.calls == [("feed", "tester", "ana")]
    # without the CA the certificate is not trusted: one line, exit 2, nothing done
    proc = _fishfarm("status", "--connect", f"tls/localhost:{port}", "--user", "viewer",
                     "--password", farm.passwords["viewer"], "--timeout", "1")
    assert proc.returncode == 2 and proc.stdout == "" and proc.stderr.count("\n") == 1
    assert "certificate is not signed by --ca" in proc.stderr
    # plain tcp to the TLS port is no session either
    proc = _fishfarm("status", "--connect", f"tcp/127.0.0.1:{port}", "--user", "viewer",
                     "--password", farm.passwords["viewer"], "--timeout", "1")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1
    assert farm.calls == [("feed", "tester", "ana")]


@pytest.mark.parametrize("years, said", [(None, None), (3, "expired on"), (-1, "is not valid before")])
def test_a_listen_certificate_out_of_date_is_refused_at_load(tmp_path, years, said):
    """An expired certificate was taken without a word: then every client was refused, e-stops
    included, and each was told its CA or password was wrong."""
    import time

    import zenoh

    from controller.errors import BadInput
    from controller.zenoh_config import _certificate_in_date
    make_certificates(tmp_path)
    zc = zenoh.Config()
    zc.insert_json5("transport/link/tls/listen_certificate", json.dumps(str(tmp_path / "controller.pem")))
    now = None if years is None else time.time() + years * 365.25 * 86400
    if said is None:
        _certificate_in_date(zc, "deploy.json5", now)
        return
    with pytest.raises(BadInput) as exc:
        _certificate_in_date(zc, "deploy.json5", now)
    assert str(exc.value).startswith(f"deploy.json5: transport.link.tls.listen_certificate: "
                                     f"{tmp_path / 'controller.pem'} {said}")
    (tmp_path / "junk.pem").write_text("not a certificate")
    zc.insert_json5("transport/link/tls/listen_certificate", json.dumps(str(tmp_path / "junk.pem")))
    with pytest.raises(BadInput, match="not a readable PEM certificate"):
        _certificate_in_date(zc, "deploy.json5")
