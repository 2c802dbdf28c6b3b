"""The Zenoh configs of the farm's sessions: the controller's (from farm.toml's ``[bus]`` or a
JSON5 file, its ACL extended with each user's own override keys by controller.identity) and a
short-lived tool's (``fishfarm override``/``status``), and one-line reasons when a tool is not
admitted. Multicast scouting is off in every one (it reaches beyond loopback)."""
from __future__ import annotations

import json
import re
import socket
import ssl
import sys
import time

import zenoh

from controller.config import BusConfig, endpoint_port
from controller.errors import BadInput
from controller.identity import bind_identities


def session_config(cfg: BusConfig, where: str | None = None) -> zenoh.Config:
    """The Zenoh config of the controller's session: cfg.config (a JSON5 file) wins over
    mode/listen/connect; multicast scouting is off in every case. ``where``: the farm.toml a
    refusal names (else ``[bus]``)."""
    if cfg.config:
        try:
            zc = zenoh.Config.from_file(cfg.config)
        except (zenoh.ZError, OSError, ValueError) as exc:
            raise BadInput(cfg.config, None, f"not a usable Zenoh config: {_one_line(exc)}") from None
        _own_password(zc, cfg.config)
        _certificate_in_date(zc, cfg.config)
        acl = json.loads(zc.get_json("access_control"))
        if acl.get("enabled"):
            _set(zc, "access_control", bind_identities(acl, cfg.config), cfg.config, "access_control")
    else:
        zc = zenoh.Config()
        # an explicit empty listen list keeps a peer from listening on every interface (its default)
        for key, value in (("mode", cfg.mode), ("listen", cfg.listen), ("connect", cfg.connect)):
            _set(zc, key if key == "mode" else f"{key}/endpoints", value, where or "[bus]", f"bus.{key}")
    zc.insert_json5("scouting/multicast/enabled", "false")
    for key, value in NO_SHM.items():
        zc.insert_json5(key, json.dumps(value))
    return zc


# Zenoh's shared memory (on by default) left a segment in /dev/shm behind every `fishfarm run`,
# a file a restart never reuses, on a controller restarted for years; the farm's sessions talk over
# TCP (loopback or the farm's network) and gain nothing from it
NO_SHM = {"transport/shared_memory/enabled": False}


def _certificate_in_date(zc: zenoh.Config, where: str, now: float | None = None) -> None:
    """The TLS certificate the controller listens with is valid today: an expired one was taken
    without a word, and then every client was refused (e-stops too), each told the wrong cause."""
    path = json.loads(zc.get_json("transport/link/tls/listen_certificate"))
    if not path:
        return
    key = "transport.link.tls.listen_certificate"
    decode = getattr(ssl._ssl, "_test_decode_cert", None)    # the stdlib's reader; no X.509 library here
    if decode is None:                                       # a Python without it: not checked
        return
    try:
        cert = decode(path)
    except (OSError, ssl.SSLError) as exc:
        raise BadInput(where, key, f"{path}: not a readable PEM certificate ({_one_line(exc)})") from None
    now = time.time() if now is None else now
    after, before = ssl.cert_time_to_seconds(cert["notAfter"]), ssl.cert_time_to_seconds(cert["notBefore"])
    if now > after:
        raise BadInput(where, key, f"{path} expired on {cert['notAfter']}: no client could connect, "
                                   "e-stops included (make a new one: README, TLS)")
    if now < before:
        raise BadInput(where, key, f"{path} is not valid before {cert['notBefore']}: no client could connect "
                                   "(is this machine's clock right?)")


def client_config(connect: str, user: str | None = None, password: str | None = None,
                  *, mode: str = "client", timeout_s: float = 2.0, ca: str | None = None,
                  option: str = "--connect") -> zenoh.Config:
    """A short-lived tool's session: connect to one endpoint, listen nowhere, scout nothing.
    ``ca``: the certificate (PEM) that signed a ``tls/...`` endpoint's. A malformed endpoint is
    BadInput naming ``option`` (the command's own: a survey's is --workers)."""
    if (user is None) != (password is None):    # Zenoh refused the half login, and a worker retried for good
        given, missing = ("--user", "--password") if password is None else ("--password", "--user")
        raise BadInput(missing, None, f"{given} was given without {missing}: a login needs both")
    port = endpoint_port(connect)
    if port is not None and port.isdigit() and not 1 <= int(port) <= 65535:   # Zenoh took it, then retried for good
        raise BadInput(option, None, f"{connect}: port {port} is outside 1..65535")
    zc = zenoh.Config()
    settings = {"mode": mode, "connect/endpoints": [connect], "listen/endpoints": [],
                "scouting/multicast/enabled": False, "scouting/gossip/enabled": False,
                "transport/unicast/open_timeout": max(1, int(timeout_s * 1000)), **NO_SHM}
    if user is not None or password is not None:
        settings["transport/auth/usrpwd/user"] = user or ""
        settings["transport/auth/usrpwd/password"] = password or ""
    if ca is not None:
        settings["transport/link/tls/root_ca_certificate"] = ca
    for key, value in settings.items():
        _set(zc, key, value, option, None)
    return zc


def _own_password(zc: zenoh.Config, where: str) -> None:
    """The controller's own login (``transport.auth.usrpwd.user``, to reach an upstream router)
    with an empty password takes its password from the credentials file, so no config file holds
    one. A missing credentials file is BadInput saying how to make one."""
    path = json.loads(zc.get_json("transport/auth/usrpwd/dictionary_file"))
    if path is None:
        return
    try:
        lines = open(path, encoding="utf-8").read().splitlines()  # noqa: SIM115 - read at once
    except OSError as exc:
        raise BadInput(path, None, f"credentials file: {exc.strerror or exc} "
                       f"(make one: fishfarm credentials --out {path})") from None
    user = json.loads(zc.get_json("transport/auth/usrpwd/user"))
    if user is None or json.loads(zc.get_json("transport/auth/usrpwd/password")) != "":
        return
    passwords = dict(line.split(":", 1) for line in lines if ":" in line)
    if user not in passwords:
        raise BadInput(path, user, f"no password for the controller's own user (named in {where})")
    _set(zc, "transport/auth/usrpwd/password", passwords[user], where, "transport.auth.usrpwd.password")


def _set(zc: zenoh.Config, key: str, value, where: str, field: str | None) -> None:
    try:
        zc.insert_json5(key, json.dumps(value))
    except zenoh.ZError as exc:
        raise BadInput(where, field, _one_line(exc)) from None


def _one_line(exc: BaseException) -> str:
    """Zenoh's message on one line, without the Rust source locations it appends."""
    text = re.sub(r"\s+at /\S+:\d+\.?", "", " ".join(str(exc).split()))
    quoted = re.search(r'msg: "(.*?)"', text)  # a JSON5 error wraps the message in a Rust struct
    return ((quoted.group(1) if quoted else text).strip(" .!") or type(exc).__name__)[:300]


def _why_unreachable(connect: str, user: str | None, detail: str) -> str:
    """Tell 'nobody listens there' from 'a Zenoh node is there but would not admit us'."""
    m = re.fullmatch(r"(?:tcp|tls)/\[?([^\]]+?)\]?:(\d+)", connect)
    if m is None:
        return f"could not connect to {connect}: {detail}"
    try:
        socket.create_connection((m.group(1), int(m.group(2))), timeout=1.0).close()
    except OSError as exc:
        return f"could not connect to {connect}: {exc.strerror or exc} (is the controller running?)"
    if connect.startswith("tls/"):
        return (f"{connect} refused the session: its certificate is not signed by --ca, or "
                + (f"authentication failed for user {user!r}" if user else "it requires --user/--password"))
    # a node that takes the connection but opens no session: it refused us, or it does not answer
    # at all (a controller frozen or overloaded: the kernel accepts for it)
    if user:
        return (f"{connect} opened no session: authentication failed for user {user!r}, or nothing there "
                "answers (a frozen or overloaded controller)")
    return (f"{connect} opened no session: it requires --user/--password, or nothing there answers "
            "(a frozen or overloaded controller)")


CLIENT_RETRY_S = 1.0      # wall: a client waiting for a listener asks again this often


def open_client(connect: str, user: str | None, password: str | None, stop, who: str):
    """A client session, retried every CLIENT_RETRY_S while nobody listens at ``connect`` (said
    once on stderr, as ``who``: a worker or simulator started before the controller is normal);
    None once ``stop`` (a threading.Event) is set."""
    said = False
    while not stop.is_set():
        try:
            return zenoh.open(client_config(connect, user, password, timeout_s=2.0))
        except zenoh.ZError as exc:
            if not said:
                why = _why_unreachable(connect, user, _one_line(exc))
                print(f"{who}: {why}; retrying every {CLIENT_RETRY_S:g} s", file=sys.stderr, flush=True)
                said = True
            stop.wait(CLIENT_RETRY_S)
    return None
