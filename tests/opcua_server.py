"""A real asyncua OPC UA server on 127.0.0.1 shaped like a SINUMERIK 840D sl, for the tests.

The nodes are named and typed as the controller's (``ns=2`` string node ids):

* the temperature compensation setting data of machine axis ``axis`` (SD 43900/43910/43920,
  ``/NC/_N_AX_SEA_ACX/$SA_TEMP_COMP_ABS_VALUE[u3]`` ..., ``Double``: the default template of
  :mod:`rafi.deploy.target_sinumerik`), writable by the one configured user only;
* a ``Float`` ``/Plc/DB200.DBD0`` (writable), for the write of another type;
* the spindle speed ``/Channel/Spindle/actSpeed[u1]`` (``Double``, r/min);
* the temperatures as PLC values: T1..T8 as ``Int16`` in 0.1 degC (``/Plc/DB100.DBW<2i>``),
  T9..T16 as ``Float`` in degC (``/Plc/DB101.DBD<4i>``); read-only;
* the displacement probe ``/Channel/Probe/displacement_um`` (``Double``, um; read-only) and a
  spindle speed command ``/Channel/Spindle/speedCommand`` (``Double``, r/min; writable, as a
  variable an NC program reads), for ``rafi record``.

Like the controller, the server refuses a write whose variant type is not the node's
(``BadTypeMismatch``, asyncua's own check) or that carries a timestamp
(``BadWriteNotSupported``), and an anonymous session may read but not write
(``BadUserAccessDenied``); a wrong password is refused at login.

With ``security=ServerSecurity(...)`` the server offers *only* encrypted endpoints
(Basic256Sha256 and Aes128_Sha256_RsaOaep, each Sign and SignAndEncrypt) with its own
certificate, and accepts a client only if the client's certificate is valid, names the client's
application URI, and is in the server's folder of trusted clients (asyncua's ``TrustStore`` and
``CertificateValidator``). :func:`make_certificate` writes a self-signed certificate and key
(for a server, or for a client, valid or not) for a test. Without it, as before: NoSecurity only.

Every write a client makes is recorded server-side, in order (:attr:`SinumerikLikeServer.writes`,
accepted ones; :attr:`refused`, the others). The server runs in a thread with its own event
loop; every method is synchronous and waits a bounded time.
"""

from __future__ import annotations

import asyncio
import datetime
import logging
import math
import socket
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from asyncua import Server, ua
from asyncua.crypto.permission_rules import USER_TYPES, PermissionRuleset, User, UserRole
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

#: The server's own INFO lines (a session closed, a connection lost) are not what the tests look
#: at, and a test's captured stderr must hold only what rafi printed: the server logs warnings
#: and errors only (its loggers are asyncua.server.*, never the client's).
logging.getLogger("asyncua.server").setLevel(logging.WARNING)

NS_URI = "http://rafi.test/sinumerik-like"
SD_TEMPLATE = "/NC/_N_AX_SEA_ACX/$SA_{data}[u{axis}]"
SD_NAMES = ("TEMP_COMP_ABS_VALUE", "TEMP_COMP_SLOPE", "TEMP_COMP_REF_POSITION")
SPEED_NODE = "/Channel/Spindle/actSpeed[u1]"
PLC_COMP_NODE = "/Plc/DB200.DBD0"  # a Float a PLC program could pass on (a second write type)
DISP_NODE = "/Channel/Probe/displacement_um"  # the displacement probe (rafi record)
SPEED_COMMAND_NODE = "/Channel/Spindle/speedCommand"  # the speed a test plan commands (rafi record)
WAIT_S = 20.0


def temp_node(i: int) -> tuple[str, ua.VariantType, float]:
    """Node name, variant type and scale (degC per raw unit) of sensor ``T<i>`` (1-based)."""
    if i <= 8:
        return f"/Plc/DB100.DBW{2 * (i - 1)}", ua.VariantType.Int16, 0.1
    return f"/Plc/DB101.DBD{4 * (i - 9)}", ua.VariantType.Float, 1.0


def input_settings() -> dict:
    """``deploy.opcua.inputs`` for this server: the speed node and T1..T16 with their scales."""
    out = {"speed_rpm": SPEED_NODE}
    for i in range(1, 17):
        name, _, scale = temp_node(i)
        out[f"T{i}"] = {"node": name, "scale": scale}
    return out


def as_read(temps) -> np.ndarray:
    """The temperatures as a client reads them back: Int16 in 0.1 degC, Float (single) in degC."""
    out = []
    for i, t in enumerate(temps, start=1):
        _, vtype, scale = temp_node(i)
        if not math.isfinite(t):
            out.append(math.nan)
        elif vtype == ua.VariantType.Int16:
            out.append(float(int(round(t / scale))) * scale)
        else:
            out.append(float(np.float32(t)))
    return np.array(out)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


SERVER_URI = "urn:rafi.test:sinumerik-like"

#: The endpoints of a secure server: no NoSecurity.
SECURE_POLICIES = (
    ua.SecurityPolicyType.Basic256Sha256_Sign,
    ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
    ua.SecurityPolicyType.Aes128Sha256RsaOaep_Sign,
    ua.SecurityPolicyType.Aes128Sha256RsaOaep_SignAndEncrypt,
)


def make_certificate(
    folder: Path, name: str, uri: str, *, server: bool, days=(-1, 365), host: str = "localhost"
) -> tuple[Path, Path]:
    """A self-signed application certificate ``<folder>/<name>.der`` and its key
    ``<folder>/private/<name>.pem`` (mode 600; apart, so that ``folder`` can be a trust
    folder), valid from ``days[0]`` to ``days[1]`` days from now (both negative: expired), for a
    server or a client with application URI ``uri``."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    now = datetime.datetime.now(datetime.UTC)
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    usage = ExtendedKeyUsageOID.SERVER_AUTH if server else ExtendedKeyUsageOID.CLIENT_AUTH
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now + datetime.timedelta(days=days[0]))
        .not_valid_after(now + datetime.timedelta(days=days[1]))
        .add_extension(
            x509.SubjectAlternativeName([x509.UniformResourceIdentifier(uri), x509.DNSName(host)]), False
        )
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), False)
        .add_extension(x509.KeyUsage(True, True, True, True, False, False, False, False, False), True)
        .add_extension(x509.ExtendedKeyUsage([usage]), False)
        .sign(key, hashes.SHA256())
    )
    (folder / "private").mkdir(parents=True, exist_ok=True)
    cert_path, key_path = folder / f"{name}.der", folder / "private" / f"{name}.pem"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.DER))
    key_path.write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
    )
    key_path.chmod(0o600)
    return cert_path, key_path


@dataclass(frozen=True)
class ServerSecurity:
    """The encrypted-only server: its certificate and key, and the folder of client
    certificates it trusts (``*.der`` / ``*.pem``)."""

    certificate: Path
    private_key: Path
    trusted_clients: Path


@dataclass(frozen=True)
class Write:
    """One client write as the server saw it."""

    node: str  # the string identifier, without ns=2;s=
    value: object
    variant_type: str
    user: str | None
    status: str  # "Good" or the refusal


class _Users:
    def __init__(self, user: str, password: str):
        self.user, self.password = user, password

    def get_user(self, iserver, username=None, password=None, certificate=None):
        if username is None:
            return User(role=UserRole.Anonymous)
        if username == self.user and password == self.password:
            return User(role=UserRole.User, name=username)
        return None  # BadUserAccessDenied at login


class _Rules(PermissionRuleset):
    """Anonymous: everything a user may do but write; the user: everything a user may do."""

    def __init__(self):
        user_ids = set(map(ua.NodeId, USER_TYPES))
        write = ua.NodeId(ua.ObjectIds.WriteRequest_Encoding_DefaultBinary)
        self._allowed = {
            UserRole.Admin: user_ids,
            UserRole.User: user_ids,
            UserRole.Anonymous: user_ids - {write},
        }

    def check_validity(self, user, action_type_id, body):
        return action_type_id in self._allowed[user.role]


class SinumerikLikeServer:
    """The server; ``start()`` / ``stop()`` / ``restart()`` (same port, values kept).

    Parameters
    ----------
    axis : int
        The machine axis whose setting data exist.
    user, password : str
        The one login that may write.
    security : ServerSecurity, optional
        Only encrypted endpoints (:data:`SECURE_POLICIES`); default: NoSecurity only.
    """

    def __init__(
        self,
        *,
        axis: int = 3,
        user: str = "seawriter",
        password: str = "s3cret-Pw",
        port: int | None = None,
        security: ServerSecurity | None = None,
    ):
        self.axis = axis
        self.security = security
        self.user, self.password = user, password
        self.port = port or free_port()
        self.endpoint = f"opc.tcp://127.0.0.1:{self.port}"
        self.writes: list[Write] = []
        self.refused: list[Write] = []
        self.values: dict[str, tuple[object, ua.VariantType]] = {}
        #: node name -> the DataType the server declares for it, where not its value's type (e.g.
        #: ``ua.NodeId(ua.ObjectIds.BaseDataType)``, as some servers declare NC variables)
        self.declared_types: dict[str, ua.NodeId] = {}
        for data in SD_NAMES:
            self.values[self.sd_node(data)] = (0.0, ua.VariantType.Double)
        self.values[SPEED_NODE] = (0.0, ua.VariantType.Double)
        self.values[PLC_COMP_NODE] = (0.0, ua.VariantType.Float)
        self.values[DISP_NODE] = (0.0, ua.VariantType.Double)
        self.values[SPEED_COMMAND_NODE] = (0.0, ua.VariantType.Double)
        for i in range(1, 17):
            name, vtype, _ = temp_node(i)
            self.values[name] = (0 if vtype == ua.VariantType.Int16 else 0.0, vtype)
        self._server: Server | None = None
        #: called with each client write (a :class:`Write`) in the server's thread, before the
        #: client gets its answer: a test can act mid-write (send a signal to a client process)
        self.on_write = None
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="opcua-test-server", daemon=True)
        self._thread.start()
        self._lock = threading.Lock()

    def sd_node(self, data: str = "TEMP_COMP_ABS_VALUE") -> str:
        return SD_TEMPLATE.format(data=data, axis=self.axis)

    def _call(self, coro):
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(WAIT_S)

    # -- life cycle ----------------------------------------------------------------------
    async def _start(self) -> None:
        server = Server(user_manager=_Users(self.user, self.password))
        await server.init()
        server.set_endpoint(f"{self.endpoint}/")
        if self.security is None:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity], permission_ruleset=_Rules())
        else:
            await server.set_application_uri(SERVER_URI)
            await server.load_certificate(str(self.security.certificate))
            await server.load_private_key(str(self.security.private_key))
            server.set_security_policy(list(SECURE_POLICIES), permission_ruleset=_Rules())
            store = TrustStore([self.security.trusted_clients], [])
            await store.load_trust()
            options = (
                CertificateValidatorOptions.BASIC_VALIDATION  # valid now, the client's URI
                | CertificateValidatorOptions.TRUSTED
                | CertificateValidatorOptions.PEER_CLIENT
            )
            server.set_certificate_validator(CertificateValidator(options, store))
        server.set_identity_tokens([ua.AnonymousIdentityToken, ua.UserNameIdentityToken])
        ns = await server.register_namespace(NS_URI)
        assert ns == 2, ns
        objects = server.nodes.objects
        for name, (value, vtype) in self.values.items():
            node = await objects.add_variable(
                ua.NodeId(name, 2), ua.QualifiedName(name, 2), ua.Variant(value, vtype),
                datatype=self.declared_types.get(name),
            )  # fmt: skip
            if name.startswith("/NC/") or name in (PLC_COMP_NODE, SPEED_COMMAND_NODE):
                await node.set_writable(True)
        original = server.iserver.attribute_service.write

        async def write(params, user=None):
            user = user or User(role=UserRole.Admin)
            if user.role == UserRole.Admin:  # the server itself (the test feeding inputs)
                return await original(params, user=user)
            results = []
            for wv in params.NodesToWrite:
                dv = wv.Value
                name = wv.NodeId.Identifier
                if dv.SourceTimestamp is not None or dv.ServerTimestamp is not None:
                    code = ua.StatusCode(ua.StatusCodes.BadWriteNotSupported)
                elif user.role == UserRole.Anonymous:
                    code = ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
                else:
                    one = ua.WriteParameters()
                    one.NodesToWrite = [wv]
                    code = (await original(one, user=user))[0]
                rec = Write(name, dv.Value.Value, dv.Value.VariantType.name, user.name, code.name)
                with self._lock:
                    (self.writes if code.is_good() else self.refused).append(rec)
                    if code.is_good():
                        self.values[name] = (dv.Value.Value, dv.Value.VariantType)
                if self.on_write is not None:
                    self.on_write(rec)
                results.append(code)
            return results

        server.iserver.attribute_service.write = write
        await server.start()
        self._server = server

    def start(self) -> SinumerikLikeServer:
        self._call(self._start())
        return self

    async def _stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            await server.stop()

    def stop(self) -> None:
        self._call(self._stop())

    def restart(self) -> None:
        self.stop()
        self.start()

    def close(self) -> None:
        self.stop()
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(WAIT_S)

    # -- the machine's side --------------------------------------------------------------
    async def _set(self, name: str, value) -> None:
        _, vtype = self.values[name]
        await self._server.write_attribute_value(ua.NodeId(name, 2), ua.DataValue(ua.Variant(value, vtype)))
        self.values[name] = (value, vtype)

    async def _put_bad(self, name: str) -> None:
        dv = ua.DataValue(StatusCode=ua.StatusCode(ua.StatusCodes.BadSensorFailure))
        await self._server.write_attribute_value(ua.NodeId(name, 2), dv)

    def set_inputs(self, speed_rpm: float, temperatures, disp_um: float | None = None) -> None:
        """Put one sample on the input nodes (a NaN temperature or displacement: the sensor reads
        bad); ``disp_um`` None leaves the displacement node as it is."""

        async def put():
            await self._set(SPEED_NODE, float(speed_rpm))
            if disp_um is not None:
                if disp_um != disp_um:
                    await self._put_bad(DISP_NODE)
                else:
                    await self._set(DISP_NODE, float(disp_um))
            for i, t in enumerate(temperatures, start=1):
                name, vtype, scale = temp_node(i)
                node = ua.NodeId(name, 2)
                if t != t:  # NaN: a sensor without value, as the PLC flags it
                    dv = ua.DataValue(StatusCode=ua.StatusCode(ua.StatusCodes.BadSensorFailure))
                    await self._server.write_attribute_value(node, dv)
                    continue
                raw = int(round(t / scale)) if vtype == ua.VariantType.Int16 else float(t)
                await self._set(name, raw)

        self._call(put())

    def value(self, name: str):
        """The current value of node ``name`` (as the server holds it)."""
        with self._lock:
            return self.values[name][0]

    def client_writes(self) -> list[Write]:
        with self._lock:
            return list(self.writes)

    def __enter__(self) -> SinumerikLikeServer:
        return self.start()

    def __exit__(self, *exc) -> bool:
        self.close()
        return False
