"""The OPC UA link made safe for a plant: signed and encrypted sessions against a real asyncua
server that offers *only* encrypted endpoints (tests/opcua_server.py, ``ServerSecurity``), the
server's certificate checked (trust folder, pinned file, fingerprint; expired or not yet
valid refused), no password in plain text unless allowed, the client's certificate made by
``rafi certificate``, asyncua's log in rafi's (one line, no dumps), and a connect that Ctrl-C
or SIGTERM interrupts cleanly.

Nothing here waits for time to pass: the interrupt is sent by the listening socket the moment
the client's first bytes arrive.
"""

from __future__ import annotations

import asyncio
import gc
import logging
import signal
import socket
import threading

import pytest
import yaml

pytest.importorskip("asyncua")

from opcua_server import (  # noqa: E402
    SERVER_URI,
    ServerSecurity,
    SinumerikLikeServer,
    make_certificate,
)
from test_opcua import inputs  # noqa: E402

from rafi.cli import main  # noqa: E402
from rafi.deploy.opcua_client import (  # noqa: E402
    OpcUaLink,
    load_credentials,
    opcua_settings,
    require_credentials,
)
from rafi.deploy.opcua_log import LibraryLogRouter  # noqa: E402
from rafi.deploy.opcua_security import fingerprint  # noqa: E402
from rafi.errors import RafiUserError, SettingsError, UntrustedCertificate  # noqa: E402

USER, PASSWORD = "seawriter", "s3cret-Pw"


class Pki:
    """The certificates of one test module, in a temporary folder."""

    def __init__(self, root):
        self.root = root
        self.client_cert = root / "client" / "rafi.der"
        self.client_key = root / "client-key" / "rafi.key"
        self.server_cert, self.server_key = make_certificate(
            root / "server", "server", SERVER_URI, server=True
        )
        self.trusted_servers = root / "trusted-servers"
        self.trusted_servers.mkdir()
        (self.trusted_servers / "server.der").write_bytes(self.server_cert.read_bytes())
        self.trusted_clients = root / "trusted-clients"
        self.trusted_clients.mkdir()


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    pki = Pki(tmp_path_factory.mktemp("pki"))
    args = ["certificate", "--certificate", str(pki.client_cert), "--key", str(pki.client_key)]
    assert main(args) == 0
    (pki.trusted_clients / "rafi.der").write_bytes(pki.client_cert.read_bytes())
    return pki


@pytest.fixture(scope="module")
def secure_server(pki):
    security = ServerSecurity(pki.server_cert, pki.server_key, pki.trusted_clients)
    with SinumerikLikeServer(axis=3, security=security) as server:
        yield server


def settings(server, pki=None, **extra) -> dict:
    block = {"endpoint": server.endpoint, "inputs": inputs(), "timeout_s": 3}
    if pki is not None:
        block.update(
            security_policy="Basic256Sha256",
            certificate=str(pki.client_cert),
            private_key=str(pki.client_key),
            trust_dir=str(pki.trusted_servers),
        )
    block.update(extra)
    return opcua_settings({k: v for k, v in block.items() if v is not None})


def library_records(caplog) -> list[logging.LogRecord]:
    """Records of the link's own thread, or of asyncua's client side, that reached logging."""
    return [
        r
        for r in caplog.records
        if r.threadName == "rafi-opcua" or r.name.startswith(("asyncua.client", "asyncuagds", "asyncio"))
    ]


def test_rafi_certificate_writes_a_key_only_its_owner_reads_and_never_overwrites(pki, capsys, tmp_path):
    assert pki.client_key.stat().st_mode & 0o777 == 0o600
    args = ["certificate", "--certificate", str(pki.client_cert), "--key", str(pki.client_key)]
    before = pki.client_cert.read_bytes()
    assert main(args) == 64
    assert "exists: refused (--force replaces it)" in capsys.readouterr().err
    assert pki.client_cert.read_bytes() == before
    cert, key = tmp_path / "c.pem", tmp_path / "k.pem"
    assert (
        main(["certificate", "--certificate", str(cert), "--key", str(key), "--uri", "urn:plant:rafi"]) == 0
    )
    out = capsys.readouterr().out
    from cryptography import x509

    loaded = x509.load_pem_x509_certificate(cert.read_bytes())
    from cryptography.hazmat.primitives.serialization import Encoding

    assert f"SHA-256 fingerprint: {fingerprint(loaded.public_bytes(Encoding.DER))}" in out
    assert f"private_key: {key}" in out and "security_policy: Basic256Sha256" in out
    san = loaded.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert san.get_values_for_type(x509.UniformResourceIdentifier) == ["urn:plant:rafi"]


@pytest.mark.parametrize(
    "policy, mode, trust",
    [
        ("Basic256Sha256", "SignAndEncrypt", "trust_dir"),
        ("Aes128_Sha256_RsaOaep", "SignAndEncrypt", "server_fingerprint"),
        ("Basic256Sha256", "Sign", "server_certificate"),
        ("Aes128_Sha256_RsaOaep", "Sign", "trust_dir"),
    ],
)
def test_a_secure_session_reads_the_inputs_and_writes(secure_server, pki, caplog, policy, mode, trust):
    anchors = {
        "trust_dir": str(pki.trusted_servers),
        "server_fingerprint": fingerprint(pki.server_cert.read_bytes()),  # with colons
        "server_certificate": str(pki.server_cert),
    }
    extra = {"trust_dir": None, trust: anchors[trust]}
    s = settings(secure_server, pki, security_policy=policy, security_mode=mode, **extra)
    log = []
    value = 0.0123 if mode == "Sign" else -0.0068
    with OpcUaLink(s, user=USER, password=PASSWORD, log=log.append).connect() as link:
        secure_server.set_inputs(4000.0, [22.5] * 16)
        _, speed, temps = link.read_sample(0.0)
        link.write_value(secure_server.sd_node(), value, "Double")
    assert speed == 4000.0 and temps[0] == pytest.approx(22.5)
    last = secure_server.client_writes()[-1]
    assert (last.node, last.value, last.user) == (secure_server.sd_node(), value, USER)
    assert log == []  # no warning of any kind, from rafi or asyncua
    assert [r for r in library_records(caplog) if r.levelno >= logging.WARNING] == []


def test_rafi_deploy_writes_over_a_signed_and_encrypted_session(
    secure_server, pki, tmp_path, monkeypatch, capsys
):
    from test_live import artefact, make_registry
    from test_opcua import write_config

    make_registry(tmp_path / "results" / "m1" / "registry", artefact())
    args = write_config(tmp_path, secure_server, deploy={"interval_s": 0.05})
    config = yaml.safe_load(open(args.config, encoding="utf-8"))
    opcua = config["machines"]["m1"]["deploy"]["opcua"]
    del opcua["allow_insecure"]
    opcua.update(
        security_policy="Aes128_Sha256_RsaOaep",
        certificate=str(pki.client_cert),
        private_key=str(pki.client_key),
        server_fingerprint=fingerprint(pki.server_cert.read_bytes()),
    )
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    monkeypatch.setenv("RAFI_OPCUA_USER", USER)
    monkeypatch.setenv("RAFI_OPCUA_PASSWORD", PASSWORD)
    secure_server.set_inputs(6000.0, [20.0] * 16)
    before = len(secure_server.client_writes())
    assert main(["deploy", "--machine", "m1", "--config", args.config, "--cycles", "2"]) == 0
    assert [w.user for w in secure_server.client_writes()[before:]] == [USER, USER]
    assert "asyncua" not in capsys.readouterr().out


def test_a_password_never_goes_in_plain_text_unless_allowed(secure_server, pki):
    listener = SilentServer(interrupt=None)
    try:
        s = opcua_settings({"endpoint": listener.endpoint, "inputs": inputs()})
        with pytest.raises(SettingsError, match="would cross the network unencrypted") as refused:
            OpcUaLink(s, user=USER, password=PASSWORD)
        assert refused.value.exit_status == 64 and "\n" not in str(refused.value)
        assert listener.accepted == 0  # refused before connecting
    finally:
        listener.close()
    with SinumerikLikeServer(axis=3) as plain:  # NoSecurity only, as before
        log = []
        link = OpcUaLink(settings(plain, allow_insecure=True), user=USER, password=PASSWORD, log=log.append)
        with link.connect():
            link.write_value(plain.sd_node(), 0.001, "Double")
            link.connect()  # a reconnect: the warning was said at the start
        assert len(log) == 1 and "WARNING allow_insecure" in log[0] and "unencrypted" in log[0]
        assert plain.client_writes()[-1].user == USER
        log.clear()
        with OpcUaLink(settings(plain, allow_insecure=True), log=log.append).connect() as anonymous:
            anonymous.read_inputs()
        assert len(log) == 1 and "anonymous, so no password is sent" in log[0]
        log.clear()
        with OpcUaLink(settings(plain), log=log.append).connect() as anonymous:  # read-only: allowed
            anonymous.read_inputs()
        assert log == []


def test_an_untrusted_server_certificate_is_refused_with_one_line(secure_server, pki, tmp_path, caplog):
    other, _ = make_certificate(tmp_path / "other", "other", SERVER_URI, server=True)
    server_fp = fingerprint(pki.server_cert.read_bytes())
    cases = {
        "not trusted by deploy.opcua.trust_dir": {"trust_dir": str(other.parent)},
        "not the one deploy.opcua.server_fingerprint names": {
            "trust_dir": None, "server_fingerprint": fingerprint(other.read_bytes()).replace(":", "")
        },
        "differs from deploy.opcua.server_certificate": {"trust_dir": None, "server_certificate": str(other)},
    }  # fmt: skip
    before = len(secure_server.client_writes())
    for reason, extra in cases.items():
        log = []
        link = OpcUaLink(settings(secure_server, pki, **extra), user=USER, password=PASSWORD, log=log.append)
        with pytest.raises(UntrustedCertificate) as refused:
            link.connect()
        link.close()
        message = str(refused.value)
        assert reason in message and server_fp in message and "subject 'CN=server'" in message
        assert refused.value.exit_status == 64 and "\n" not in message and log == []
    assert len(secure_server.client_writes()) == before
    assert [r for r in library_records(caplog) if r.levelno >= logging.WARNING] == []


def test_a_client_the_server_does_not_trust_or_a_policy_it_lacks_is_one_line(secure_server, pki, tmp_path):
    cert, key = make_certificate(tmp_path / "c", "stranger", "urn:stranger", server=False)
    stranger = settings(secure_server, pki, certificate=str(cert), private_key=str(key))
    with OpcUaLink(stranger, user=USER, password=PASSWORD) as link:
        with pytest.raises(
            RafiUserError, match="the server refused the client's certificate .*BadCertificate"
        ):
            link.connect()
    with SinumerikLikeServer(axis=3) as plain, OpcUaLink(settings(plain, pki)) as link:
        with pytest.raises(
            SettingsError, match="offers no endpoint Basic256Sha256/SignAndEncrypt; it offers None/None:"
        ):
            link.connect()


@pytest.mark.parametrize("days, reason", [((-30, -1), "expired on"), ((2, 30), "is not valid before")])
def test_a_server_certificate_out_of_its_validity_is_refused(pki, tmp_path, days, reason):
    cert, key = make_certificate(tmp_path / "srv", "server", SERVER_URI, server=True, days=days)
    security = ServerSecurity(cert, key, pki.trusted_clients)
    with SinumerikLikeServer(axis=3, security=security) as server:
        pinned = settings(server, pki, trust_dir=str(cert.parent))  # trusted, but not valid now
        with OpcUaLink(pinned, user=USER, password=PASSWORD) as link:
            with pytest.raises(
                UntrustedCertificate, match=f"the server's certificate .* {reason}"
            ) as refused:
                link.connect()
        assert fingerprint(cert.read_bytes()) in str(refused.value)
        assert server.client_writes() == []


def test_security_settings_are_checked_before_anything_connects(pki, tmp_path):
    base = {"endpoint": "opc.tcp://127.0.0.1:4840", "inputs": {"speed_rpm": "/s"}}
    cases = {
        "nothing says which server certificate to trust.*never trusts a server on first use": {
            "security_policy": "Basic256Sha256", "certificate": str(pki.client_cert),
            "private_key": str(pki.client_key),
        },
        "'Basic128Rsa15'; expected none, Basic256Sha256": {"security_policy": "Basic128Rsa15"},
        "deploy.opcua.certificate is not set": {"security_policy": "Basic256Sha256", "trust_dir": "/x"},
        "security_mode is 'Encrypt'": {"security_mode": "Encrypt"},
        "server_fingerprint .* 64 hex digits": {
            "security_policy": "Basic256Sha256", "certificate": "c", "private_key": "/k",
            "server_fingerprint": "AB",
        },
        "certificate is set but security_policy is none": {"certificate": str(pki.client_cert)},
        "allow_insecure is 'yes'": {"allow_insecure": "yes"},
    }  # fmt: skip
    for message, extra in cases.items():
        with pytest.raises(SettingsError, match=message):
            opcua_settings({**base, **extra})
    good = {
        **base, "security_policy": "aes128_sha256_rsaoaep", "certificate": str(pki.client_cert),
        "private_key": str(pki.client_key), "server_fingerprint": "ab" * 32,
    }  # fmt: skip
    assert opcua_settings(good)["security_policy"] == "Aes128_Sha256_RsaOaep"
    open_key = tmp_path / "open.key"
    open_key.write_bytes(pki.client_key.read_bytes())
    open_key.chmod(0o644)
    with pytest.raises(SettingsError, match="mode 644.*chmod 600"):
        OpcUaLink(opcua_settings({**good, "private_key": str(open_key)}))
    other_cert, other_key = make_certificate(tmp_path / "o", "o", "urn:o", server=False)
    with pytest.raises(SettingsError, match="is not the key of deploy.opcua.certificate"):
        OpcUaLink(opcua_settings({**good, "private_key": str(other_key)}))
    old_cert, old_key = make_certificate(tmp_path / "old", "old", "urn:o", server=False, days=(-9, -2))
    with pytest.raises(SettingsError, match="expired on .*rafi certificate --force"):
        OpcUaLink(opcua_settings({**good, "certificate": str(old_cert), "private_key": str(old_key)}))
    project = tmp_path / "project"
    (project / ".git").mkdir(parents=True)
    with pytest.raises(RafiUserError, match="private_key .* inside .*project"):
        opcua_settings({**good, "private_key": "pki/rafi.key"}, project_dir=project)


def test_credentials_messages_say_where_they_were_looked_for(tmp_path):
    s = opcua_settings({"endpoint": "opc.tcp://h:4840", "inputs": {"speed_rpm": "/s"}})
    missing = tmp_path / "nowhere.credentials"
    with pytest.raises(RafiUserError, match="named by the environment variable RAFI_OPCUA_CREDENTIALS"):
        load_credentials(s, environ={"RAFI_OPCUA_CREDENTIALS": str(missing)})
    with pytest.raises(RafiUserError, match="named by deploy.opcua.credentials_file.*does not exist") as e:
        load_credentials({**s, "credentials_file": str(missing)}, environ={})
    assert "'user: NAME' and 'password: SECRET'" in str(e.value) and "chmod 600" in str(e.value)
    assert "docs/deploy.md#credentials" in str(e.value)
    require_credentials("seawriter", s)  # a user: nothing to say
    with pytest.raises(RafiUserError, match="no OPC UA user is configured.*RAFI_OPCUA_USER") as e:
        require_credentials(None, s)
    assert e.value.exit_status == 64 and "--dry-run needs none" in str(e.value)


def test_a_wrong_password_gives_rafis_one_line_and_no_library_dump(secure_server, pki, caplog, capfd):
    log = []
    link = OpcUaLink(settings(secure_server, pki), user=USER, password="wrong", log=log.append)
    with pytest.raises(
        RafiUserError, match="the login was refused for user 'seawriter': BadUserAccessDenied"
    ):
        link.connect()
    link.close()
    assert log == []
    assert [r for r in library_records(caplog) if r.levelno >= logging.WARNING] == []
    assert "ServiceFault" not in capfd.readouterr().err


def test_library_log_one_line_per_event_and_repeats_counted():
    now, shown = [0.0], []
    router = LibraryLogRouter(shown.append, window_s=60, clock=lambda: now[0])

    def record(message, level=logging.WARNING):
        return logging.LogRecord("asyncua.client", level, __file__, 1, message, None, None)

    router.handle(record("close_secure_channel was called but connection is closed"))  # debug: not shown
    router.handle(record("close_session was called but connection is closed"))  # at every outage: neither
    router.handle(record("Requested session timeout to be 3600000ms, got 600000ms instead"))
    router.handle(record("ServiceFault (BadUserAccessDenied, diagnostics: DiagnosticInfo(...))"))
    router.handle(record("Sending plain-text password"))
    router.handle(record("just a note", logging.INFO))
    assert shown == []
    for _ in range(6):
        router.handle(record("socket lost\nTraceback (most recent call last): ..."))
    assert shown == ["OPC UA (asyncua) warning: socket lost"]
    now[0] = 61.0
    router.handle(record("something else", logging.ERROR))
    assert shown[1:] == [
        "OPC UA (asyncua) warning: socket lost (repeated 5 times)",
        "OPC UA (asyncua) error: something else",
    ]
    router.handle(record("something else", logging.ERROR))
    router.flush()
    assert shown[3:] == ["OPC UA (asyncua) error: something else (repeated 1 times)"]


class SilentServer:
    """Accepts TCP connections and never answers; on the first bytes received, sends
    ``interrupt`` (a signal number) to the main thread, if given."""

    def __init__(self, interrupt: int | None):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen()
        self.endpoint = f"opc.tcp://127.0.0.1:{self.sock.getsockname()[1]}"
        self.interrupt = interrupt
        self.accepted = 0
        self.connections = []
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self):
        main_thread = threading.main_thread().ident
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.accepted += 1
            self.connections.append(conn)
            if conn.recv(4096) and self.interrupt is not None:  # the client's Hello: it now waits
                signal.pthread_kill(main_thread, self.interrupt)

    def close(self):
        self.sock.shutdown(socket.SHUT_RDWR)  # wakes the accept() of the thread
        self.sock.close()
        for conn in self.connections:
            conn.close()
        self._thread.join(5)


def _sigterm_as_interrupt(signum, frame):  # as `rafi deploy` does
    raise KeyboardInterrupt


@pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning")
@pytest.mark.filterwarnings("error::RuntimeWarning")  # "coroutine ... was never awaited"
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("how", ["connect", "try_reconnect"])
def test_ctrl_c_or_sigterm_while_connecting_reaches_the_caller_and_leaves_nothing(caplog, capfd, signum, how):
    handler = signal.default_int_handler if signum == signal.SIGINT else _sigterm_as_interrupt
    previous = signal.signal(signum, handler)
    server = SilentServer(interrupt=signum)
    log = []
    try:
        link = OpcUaLink(opcua_settings({"endpoint": server.endpoint, "inputs": inputs(), "timeout_s": 30}))
        link.log = log.append
        with pytest.raises(KeyboardInterrupt):
            getattr(link, how)()
        assert not link._loop_thread.running  # connect stopped its thread
        assert not [t for t in threading.enumerate() if t.name == "rafi-opcua"]
        link.close()
        link.close()
    finally:
        signal.signal(signum, previous)
        server.close()
    gc.collect()  # a task left pending would say so now ("Task was destroyed but it is pending!")
    leaked = [t for t in gc.get_objects() if isinstance(t, asyncio.Task) and not t.done()]
    assert [t for t in leaked if t.get_loop().is_closed()] == []  # (the test servers' loops run)
    # try_reconnect probes the port first: a TCP connection closed at once, no byte sent
    assert server.accepted == (1 if how == "connect" else 2) and log == []
    assert [r for r in library_records(caplog) if r.levelno >= logging.WARNING] == []
    assert capfd.readouterr().err == ""


@pytest.mark.parametrize("user", [USER, None])
def test_allow_insecure_against_an_encrypted_only_server_says_so_not_a_certificate(secure_server, user):
    """No security_policy (allow_insecure for the password) against a server that offers only
    encrypted endpoints: one line saying the server refuses unencrypted sessions, what to set;
    no certificate is involved, so none is named."""
    plain = settings(secure_server, allow_insecure=True)
    before = len(secure_server.client_writes())
    with OpcUaLink(plain, user=user, password=PASSWORD if user else None) as link:
        with pytest.raises(RafiUserError) as refused:
            link.connect()
    message = str(refused.value)
    assert message.startswith(f"OPC UA {secure_server.endpoint}: the server refuses unencrypted sessions (")
    assert "set deploy.opcua.security_policy" in message and "certificate (none)" not in message
    assert refused.value.exit_status == 64 and "\n" not in message
    assert len(secure_server.client_writes()) == before


def test_a_server_that_rejects_the_security_mode_is_said_apart_from_a_certificate_refusal():
    """A server that lists an unencrypted endpoint but rejects the session (as a SINUMERIK
    configured for encryption only does: BadSecurityModeRejected) is the same "unencrypted"
    refusal without a policy; with one, the status is a certificate or policy matter."""
    from asyncua import ua

    from rafi.deploy.opcua_errors import refusal

    where = dict(endpoint="opc.tcp://cnc:4840", user="seawriter", certificate=None)
    for status in ("BadSecurityModeRejected", "BadSecurityPolicyRejected"):
        exc = ua.UaStatusCodeError(getattr(ua.StatusCodes, status))
        plain = str(refusal(exc, "the login", secure=False, **where))
        said = "OPC UA opc.tcp://cnc:4840: the server refuses unencrypted sessions ("
        assert plain.startswith(said + status)
        assert "certificate (none)" not in plain
        secure = str(refusal(exc, "the login", secure=True, **{**where, "certificate": "/etc/rafi/c.der"}))
        assert "refused the client's certificate /etc/rafi/c.der" in secure and status in secure
    assert refusal(ConnectionRefusedError(111, "refused"), "the login", secure=False, **where) is None
