"""The OPC UA link of the live loop (``rafi deploy``): read the inputs, write the compensation.

The only module of ``rafi`` that imports ``asyncua`` (the ``deploy`` extra), and only when a
link is created, so that ``rafi`` works without it. ``docs/deploy.md`` ("Live: OPC UA")
describes every setting for a controls engineer.

* :func:`opcua_settings` checks the ``deploy.opcua`` block of ``config.yaml`` and fills in its
  defaults; a user name or password there is refused (they go to the environment or a
  credentials file, :func:`rafi.deploy.opcua_credentials.load_credentials`). The security keys
  (a signed and encrypted session, whom to trust) are :mod:`rafi.deploy.opcua_security`'s.
* A password never crosses the network as plain text unless ``allow_insecure: true`` (then a
  warning at every start); an untrusted server certificate is refused with one line.
* :class:`OpcUaLink` holds one session to the server. It is synchronous for its caller (the
  asyncua client runs in a background thread with its own event loop) and is both the *source*
  of the live loop (:meth:`OpcUaLink.read_sample`) and the *sink* of
  :class:`rafi.deploy.target_sinumerik.SinumerikTarget` (:meth:`OpcUaLink.write_value`).
  A value is written as ``ua.DataValue(ua.Variant(value, <the node's own variant type>))``
  without timestamps (a SINUMERIK refuses a write of another type, or with timestamps,
  ``../shared/docs/controllers.md``); the node's type is read once.
* A lost connection raises the built-in :class:`ConnectionError` from a read or a write; the
  caller (:class:`rafi.deploy.live.LiveLoop`) then writes nothing and calls
  :meth:`OpcUaLink.try_reconnect` on each cycle, which probes the port and tries a session as
  soon as it answers again, else after a short doubling back-off (``reconnect_min_s`` ..
  ``reconnect_max_s``; :mod:`rafi.deploy.opcua_reconnect`). A refusal that reconnecting cannot
  cure (credentials, the right to write, a wrong node or data type, a certificate, an
  unencrypted session) is a :class:`rafi.errors.RafiUserError` (:mod:`rafi.deploy.opcua_errors`)
  and stops the loop.
* Ctrl-C / SIGTERM (a KeyboardInterrupt in the caller's thread) while a call waits: the call's
  task is cancelled on the link's event loop and KeyboardInterrupt goes on to the caller;
  while connecting, the link is closed too (its thread stopped, nothing left pending).
  asyncua's own log goes to ``log`` while the link is open (:mod:`rafi.deploy.opcua_log`).
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable, Mapping

import numpy as np

from rafi.contract.sensors import DEFAULT_SENSORS
from rafi.deploy.opcua_credentials import (
    ENV_CREDENTIALS,
    ENV_PASSWORD,
    ENV_USER,
    SECRET_KEYS,
    load_credentials,
    require_credentials,
)
from rafi.deploy.opcua_errors import refusal
from rafi.deploy.opcua_log import LibraryLogRouter, route_library_log, unroute_library_log
from rafi.deploy.opcua_loop import LoopThread, call_within
from rafi.deploy.opcua_reconnect import ReconnectPolicy, endpoint_address, port_problem
from rafi.deploy.opcua_security import check_security_settings, load_security, plaintext_notice, secure_client
from rafi.errors import RafiUserError, SettingsError
from rafi.readers.input_spec import sensor_name_problem

__all__ = [
    "ENV_CREDENTIALS",
    "ENV_PASSWORD",
    "ENV_USER",
    "OPCUA_DEFAULTS",
    "OpcUaLink",
    "load_credentials",
    "opcua_settings",
    "require_credentials",
]

#: The keys of ``deploy.opcua`` and their defaults (``endpoint`` is required).
OPCUA_DEFAULTS = {
    "endpoint": None,  # opc.tcp://host:4840
    "inputs": {},  # speed_rpm / the sensors -> node id, or {node, scale, offset}
    "node_prefix": "ns=2;s=",  # put before a node name that is not a full node id
    "credentials_file": None,  # outside the project; RAFI_OPCUA_CREDENTIALS overrides it
    "timeout_s": 5.0,  # per request
    # after a lost connection: a TCP probe of the port every cycle, a session as soon as it answers;
    # while it answers but the session fails, these waits between sessions (opcua_reconnect)
    "reconnect_min_s": 1.0,  # first wait after a failed session
    "reconnect_max_s": 8.0,  # the wait doubles up to this
    # security (rafi.deploy.opcua_security; docs/deploy.md "Security")
    "security_policy": None,  # none, Basic256Sha256, Aes128_Sha256_RsaOaep, Aes256_Sha256_RsaPss
    "security_mode": "SignAndEncrypt",  # or Sign
    "certificate": None,  # the client's certificate (PEM or DER), `rafi certificate` writes one
    "private_key": None,  # its private key (PEM or DER, unencrypted, mode 600, outside the project)
    "server_certificate": None,  # trust: the server's certificate, pinned
    "trust_dir": None,  # trust: a folder of trusted server or CA certificates (*.der, *.pem)
    "server_fingerprint": None,  # trust: SHA-256 of the server's certificate (hex, colons allowed)
    "allow_insecure": False,  # true: a password may go unencrypted (a warning at every start)
}

#: The session timeout asked of the server: a session of a client that died is freed after it
#: (a SINUMERIK has few session slots); the client's watchdog reads every second meanwhile.
SESSION_TIMEOUT_MS = 60_000

#: Variant types a compensation (a float) may be written as, exactly.
_FLOAT_TYPES = ("Double", "Float")


def _asyncua():
    """The ``asyncua`` package, or a RafiUserError saying how to install it."""
    try:
        import asyncua
    except ImportError:
        raise RafiUserError(
            "the OPC UA client needs the asyncua package: pip install 'rafi[deploy]'"
        ) from None
    return asyncua


# --------------------------------------------------------------------------- settings


def _positive(block: dict, key: str) -> float:
    value = block[key]
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not (math.isfinite(value) and value > 0)
    ):
        raise SettingsError(f"deploy.opcua.{key} is {value!r}; expected a number of seconds above 0")
    return float(value)


def _node_id(value, prefix: str, where: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise SettingsError(f"{where} is {value!r}; expected a node id such as 'ns=2;s=/Channel/...'")
    value = value.strip()
    full = value.startswith(("ns=", "nsu=", "i=", "s=", "g=", "b="))
    return value if full else prefix + value


def opcua_settings(block: Mapping | None, *, need_inputs: bool = True, project_dir=".") -> dict:
    """The ``deploy.opcua`` block checked, with its defaults filled in.

    Parameters
    ----------
    block : mapping or None
        ``machine_settings(config, m)["deploy"]["opcua"]``.
    need_inputs : bool
        The inputs are read from the server (not from a followed log file): ``inputs`` must
        name the speed.
    project_dir : path
        The folder of ``config.yaml``: a relative certificate or key path is taken from it.

    Returns
    -------
    dict
        The keys of :data:`OPCUA_DEFAULTS`; ``inputs`` as ``{name: (node_id, scale, offset)}``
        (value read = raw * scale + offset), node ids complete; the security keys as
        :func:`rafi.deploy.opcua_security.check_security_settings` leaves them (paths absolute).

    Raises
    ------
    SettingsError
        A missing endpoint, an unknown key, a user name or password in the block (they belong
        in the environment or a credentials file), a malformed input, a security setting.
    """
    _check_keys(block)
    out = {**OPCUA_DEFAULTS, **block}
    _check_endpoint(out["endpoint"])
    if not isinstance(out["node_prefix"], str):
        raise SettingsError(
            f"deploy.opcua.node_prefix is {out['node_prefix']!r}; expected text such as 'ns=2;s='"
        )
    for key in ("timeout_s", "reconnect_min_s", "reconnect_max_s"):
        out[key] = _positive(out, key)
    if out["reconnect_max_s"] < out["reconnect_min_s"]:
        raise SettingsError("deploy.opcua.reconnect_max_s is below reconnect_min_s")
    cred = out["credentials_file"]
    if cred is not None and (not isinstance(cred, str) or not cred):
        raise SettingsError(f"deploy.opcua.credentials_file is {cred!r}; expected a path")
    inputs = out["inputs"] or {}
    if not isinstance(inputs, Mapping):
        raise SettingsError("deploy.opcua.inputs must map speed_rpm and the machine's sensors to node ids")
    parsed = {name: _input_node(name, spec, out["node_prefix"]) for name, spec in inputs.items()}
    if need_inputs and "speed_rpm" not in parsed:
        raise SettingsError("deploy.opcua.inputs has no speed_rpm node (the spindle speed)")
    out["inputs"] = parsed
    return check_security_settings(out, project_dir)


def _check_keys(block) -> None:
    """``deploy.opcua`` is a mapping of known keys, none of them a credential."""
    if block is None:
        raise SettingsError("deploy.opcua is not set: the live loop needs at least deploy.opcua.endpoint")
    if not isinstance(block, Mapping):
        raise SettingsError(f"deploy.opcua is {type(block).__name__}; expected a mapping")
    secrets = [k for k in block if str(k).lower() in SECRET_KEYS]
    if secrets:
        raise SettingsError(
            f"deploy.opcua.{secrets[0]}: credentials never go to config.yaml; set the environment "
            f"variables {ENV_USER} and {ENV_PASSWORD}, or name a credentials file outside the "
            f"project (mode 600) in {ENV_CREDENTIALS} or deploy.opcua.credentials_file (docs/deploy.md)"
        )
    unknown = sorted(str(k) for k in block if k not in OPCUA_DEFAULTS)
    if unknown:
        raise SettingsError(f"deploy.opcua.{unknown[0]} is not a setting; known: {sorted(OPCUA_DEFAULTS)}")


def _check_endpoint(endpoint) -> None:
    """``opc.tcp://host:port/...``, without a user name."""
    if not isinstance(endpoint, str) or not endpoint.startswith("opc.tcp://"):
        from rafi.secret_mask import masked

        raise SettingsError(f"deploy.opcua.endpoint is {masked(endpoint)!r}; expected 'opc.tcp://host:port'")
    if "@" in endpoint.split("//", 1)[1].split("/", 1)[0]:
        raise SettingsError(
            "deploy.opcua.endpoint holds a user name (user@host): credentials never go to config.yaml"
        )


def _input_node(name: str, spec, prefix: str) -> tuple[str, float, float]:
    """``(node_id, scale, offset)`` of the input ``name``: ``spec`` is a node id, or a mapping of
    ``node``, ``scale`` and ``offset``."""
    where = f"deploy.opcua.inputs.{name}"
    if name != "speed_rpm" and sensor_name_problem(name):
        raise SettingsError(f"{where}: not an input: {sensor_name_problem(name)}")
    scale, offset = 1.0, 0.0
    if isinstance(spec, Mapping):
        extra = sorted(set(spec) - {"node", "scale", "offset"})
        if extra:
            raise SettingsError(f"{where}.{extra[0]} is not a setting; known: node, scale, offset")
        scale, offset = spec.get("scale", 1.0), spec.get("offset", 0.0)
        for key, v in (("scale", scale), ("offset", offset)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise SettingsError(f"{where}.{key} is {v!r}; expected a finite number")
        if scale == 0:
            raise SettingsError(f"{where}.scale is 0")
        spec = spec.get("node")
    return _node_id(spec, prefix, where), float(scale), float(offset)


# --------------------------------------------------------------------------- the link


class OpcUaLink:
    """One OPC UA session: the live inputs, and a sink for the SINUMERIK target.

    Parameters
    ----------
    settings : mapping
        :func:`opcua_settings`.
    user, password : str, optional
        From :func:`load_credentials`; None: anonymous.
    log : callable, optional
        ``log(message)`` for each lost and restored connection, the ``allow_insecure`` warning
        and asyncua's own warnings (default: nothing).
    clock : callable
        Seconds, for the back-off (default ``time.monotonic``).
    probe : callable, optional
        ``probe() -> str | None``: why the endpoint's port does not answer, None if it does
        (default: a TCP connection to it within ``timeout_s``,
        :func:`rafi.deploy.opcua_reconnect.port_problem`).
    library_log_level : int
        asyncua's records at or above this level (after :data:`rafi.deploy.opcua_log.LEVELS`)
        go to ``log`` (default ``logging.WARNING``).

    Raises
    ------
    SettingsError
        A password that would cross the network unencrypted (no security policy) without
        ``allow_insecure``; the client's certificate or key unusable (before connecting).

    Notes
    -----
    Not thread-safe: one caller (the live loop). The asyncua client runs in a daemon thread
    with its own event loop; each call waits at most ``3 timeout_s + 1`` s for it.
    """

    def __init__(
        self,
        settings: Mapping,
        *,
        user=None,
        password=None,
        log: Callable | None = None,
        clock=None,
        probe: Callable[[], bool] | None = None,
        library_log_level: int = logging.WARNING,
    ):
        import time

        self.settings = dict(settings)
        self.endpoint = self.settings["endpoint"]
        self.inputs = dict(self.settings["inputs"])
        self.node_prefix = self.settings["node_prefix"]
        self.timeout_s = float(self.settings["timeout_s"])
        self._user, self._password = user, password
        self.log = log or (lambda message: None)
        self.clock = clock or time.monotonic
        self._notice = plaintext_notice(self.settings, user)
        self.security = load_security(self.settings)
        self._library_log = LibraryLogRouter(self.log, level=library_log_level, clock=self.clock)
        self.connected = False
        self.losses = 0
        self.reconnects = 0
        self.ever_connected = False
        self.last_error: str | None = None  # why the last try to connect failed
        self._client = None
        self._types: dict[str, object] = {}  # node id -> ua.VariantType
        self._nodes: dict[str, object] = {}
        host, port = endpoint_address(self.endpoint)
        self.reconnect = ReconnectPolicy(
            self.settings["reconnect_min_s"], self.settings["reconnect_max_s"], clock=lambda: self.clock(),
            probe=probe or (lambda: port_problem(host, port, self.timeout_s)),
        )  # fmt: skip
        self._loop_thread = LoopThread(
            "rafi-opcua",
            on_start=lambda ident: route_library_log(ident, self._library_log),
            on_stop=lambda ident: unroute_library_log(ident, self._library_log),
        )

    # -- the event loop in its thread ----------------------------------------------------
    def _run(self, coro):
        """Run ``coro`` on the link's loop and wait for it (:meth:`LoopThread.run`: an interrupt
        cancels it there and goes on to the caller)."""
        try:
            return self._loop_thread.run(coro, self.timeout_s * 3 + 1, settle_s=self.timeout_s)
        except TimeoutError:
            raise TimeoutError(f"no answer from {self.endpoint} within {self.timeout_s:g} s") from None

    def node_id(self, node: str) -> str:
        """``node`` as a complete node id (``node_prefix`` put before a bare name)."""
        return _node_id(node, self.node_prefix, "node")

    # -- connection ----------------------------------------------------------------------
    def _fatal(self, exc: BaseException, what: str) -> RafiUserError | None:
        return refusal(
            exc, what, endpoint=self.endpoint, user=self._user, certificate=self.settings.get("certificate"),
            secure=self.security is not None,
        )  # fmt: skip

    async def _connect(self):
        asyncua = _asyncua()
        client = asyncua.Client(url=self.endpoint, timeout=self.timeout_s)
        client.session_timeout = SESSION_TIMEOUT_MS
        if self._user is not None:
            client.set_user(self._user)
            client.set_password(self._password)
        try:
            if self.security is not None:
                await secure_client(client, self.security, self.endpoint, self._user, self.log)
            await client.connect()
        except asyncio.CancelledError:
            client.disconnect_socket()  # no goodbye: the server may not be answering at all
            raise
        except BaseException:
            try:
                await call_within(self.timeout_s, client.disconnect)
            except Exception:
                pass
            raise
        return client

    def connect(self) -> OpcUaLink:
        """Open the session (again). ConnectionError if the server cannot be reached,
        RafiUserError if it refuses the login or its certificate is not trusted.

        A KeyboardInterrupt while connecting closes the link (the connection attempt is
        cancelled, the loop thread stopped) and goes on to the caller.
        """
        _asyncua()
        if self._notice is not None:
            self.log(self._notice)
            self._notice = None  # once per start, not at every reconnect
        self._drop_client()
        try:
            self._client = self._run(self._connect())
        except RafiUserError:
            raise
        except Exception as exc:
            fatal = self._fatal(exc, "the login")
            if fatal is not None:
                raise fatal from None
            self.reconnect.failed()
            self.last_error = self._why_not(exc)
            raise ConnectionError(f"OPC UA {self.endpoint}: cannot connect: {self.last_error}") from None
        except BaseException:
            self._loop_thread.stop(self.timeout_s)
            raise
        self._nodes = {}
        self.connected = self.ever_connected = True
        self.reconnect.connected()
        return self

    def _why_not(self, exc: BaseException) -> str:
        """Why a session could not be opened: the port's problem if it does not answer (a TCP
        probe), else the error (asyncua's "connection lost" said as what it means here)."""
        problem = self.reconnect.check_port()
        if problem is not None:
            return problem
        if isinstance(exc, ConnectionError) and str(exc) == "connection lost":
            return "the server closed the connection before the session was open"
        return f"{type(exc).__name__}: {exc}".rstrip(": ")

    def _drop_client(self) -> None:
        client, self._client = self._client, None
        self.connected = False
        if client is not None:
            try:
                self._run(call_within(self.timeout_s, client.disconnect))
            except Exception:
                pass

    def lost(self, exc: BaseException) -> ConnectionError:
        """Record a lost connection (logged once), schedule the next try; the error to raise."""
        if self.connected:
            self.losses += 1
            self.log(
                f"OPC UA {self.endpoint}: connection lost ({type(exc).__name__}: {exc}); "
                "nothing is written until it is back"
            )
        self._drop_client()
        self.reconnect.lost()
        return ConnectionError(f"OPC UA {self.endpoint}: connection lost: {type(exc).__name__}: {exc}")

    def try_reconnect(self) -> bool:
        """Try to connect (again) if the policy says so; True when connected.

        A TCP probe of the port first: while it does not answer, no session is tried; as soon as
        it answers again, one is; while it answers and sessions fail, they wait
        ``reconnect_min_s`` doubling up to ``reconnect_max_s``
        (:class:`rafi.deploy.opcua_reconnect.ReconnectPolicy`). A refused login is not retried:
        RafiUserError.
        """
        if self.connected:
            return True
        if not self.reconnect.due():
            self.last_error = self.reconnect.problem or self.last_error
            return False
        again = self.ever_connected
        try:
            self.connect()
        except ConnectionError:
            return False
        if again:
            self.reconnects += 1
            self.log(f"OPC UA {self.endpoint}: reconnected")
        else:
            self.log(f"OPC UA {self.endpoint}: connected")
        return True

    # -- reading -------------------------------------------------------------------------
    async def _read(self, node_ids: list[str]):
        from asyncua import ua

        nodes = [self._client.get_node(n) for n in node_ids]
        return await self._client.read_attributes(nodes, ua.AttributeIds.Value)

    def read_inputs(self) -> dict[str, float]:
        """The configured inputs, scaled (raw * scale + offset); NaN where the server has no
        good value. ConnectionError when the connection is lost."""
        if not self.connected:
            raise ConnectionError(f"OPC UA {self.endpoint}: not connected")
        names = list(self.inputs)
        try:
            values = self._run(self._read([self.inputs[n][0] for n in names]))
        except Exception as exc:
            fatal = self._fatal(exc, "reading the inputs")
            if fatal is not None:
                raise fatal from None
            raise self.lost(exc) from None
        out = {}
        for name, dv in zip(names, values):
            _, scale, offset = self.inputs[name]
            raw = dv.Value.Value if (dv.StatusCode is None or dv.StatusCode.is_good()) and dv.Value else None
            try:
                value = float(raw) * scale + offset
            except (TypeError, ValueError):
                value = math.nan
            out[name] = value if math.isfinite(value) else math.nan
        return out

    def read_sample(self, t_s: float, sensors=DEFAULT_SENSORS) -> tuple[float, float, np.ndarray]:
        """``(t_s, speed_rpm, temperatures)`` from the inputs, the temperatures of the machine's
        ``sensors`` in order (NaN where not configured)."""
        values = self.read_inputs()
        temps = np.array([values.get(name, math.nan) for name in sensors], dtype=float)
        return float(t_s), values.get("speed_rpm", math.nan), temps

    # -- writing (the sink of SinumerikTarget) -------------------------------------------
    async def _variant_type(self, node_id: str):
        from asyncua import ua

        node = self._client.get_node(node_id)
        try:
            vtype = await node.read_data_type_as_variant_type()
        except Exception:
            vtype = None
        if vtype in (None, ua.VariantType.Null, ua.VariantType.Variant, ua.VariantType.ExtensionObject):
            vtype = (await node.read_data_value()).Value.VariantType
        return vtype

    async def _write(self, node_id: str, value: float, vtype):
        from asyncua import ua

        node = self._client.get_node(node_id)
        # no timestamps: a SINUMERIK refuses a write that carries them
        await node.write_attribute(ua.AttributeIds.Value, ua.DataValue(ua.Variant(value, vtype)))

    def write_value(self, node: str, value: float, datatype: str) -> None:
        """Write ``value`` to ``node`` as the node's own variant type (read once per node).

        ``datatype`` is the type the target computed the value for (``"Double"``); a node of
        another floating type is written as its own type, an integer or other type is refused.

        Raises
        ------
        ConnectionError
            The connection was lost (nothing more is written until :meth:`try_reconnect`).
        RafiUserError
            The server refused the write (no right to write, unknown node, wrong type).
        """
        if not self.connected:
            raise ConnectionError(f"OPC UA {self.endpoint}: not connected")
        node_id = self.node_id(node)
        try:
            vtype = self._types.get(node_id)
            if vtype is None:
                vtype = self._run(self._variant_type(node_id))
                if getattr(vtype, "name", None) not in _FLOAT_TYPES:
                    raise RafiUserError(
                        f"OPC UA node {node_id} is of type {getattr(vtype, 'name', vtype)}; the "
                        f"compensation is a {datatype}: refused (check the node id)"
                    )
                self._types[node_id] = vtype
            self._run(self._write(node_id, float(value), vtype))
        except RafiUserError:
            raise
        except Exception as exc:
            fatal = self._fatal(exc, f"writing {node_id}")
            if fatal is not None:
                raise fatal from None
            raise self.lost(exc) from None

    def read_nodes(self, node_ids) -> list[tuple[float, str, str]]:
        """``(value, variant type, status)`` of each node in one request (``rafi record``): the value
        NaN unless the status is good and it is a number; the type ``''`` if none came; the status
        ``'Good'``, ``'BadSensorFailure'``, ... ConnectionError: lost; RafiUserError: refused."""
        if not self.connected:
            raise ConnectionError(f"OPC UA {self.endpoint}: not connected")
        try:
            values = self._run(self._read([self.node_id(n) for n in node_ids]))
        except Exception as exc:
            fatal = self._fatal(exc, "reading nodes")
            if fatal is not None:
                raise fatal from None
            raise self.lost(exc) from None
        out = []
        for dv in values:
            code, variant = dv.StatusCode, dv.Value
            vtype = getattr(getattr(variant, "VariantType", None), "name", "")
            try:
                value = float(variant.Value) if (code is None or code.is_good()) and variant else math.nan
            except (TypeError, ValueError):
                value = math.nan
            status = "Good" if code is None else str(getattr(code, "name", code))
            out.append((value if math.isfinite(value) else math.nan, vtype, status))
        return out

    def open(self) -> None:
        """Connect if not connected (called when the target opens)."""
        if not self.connected:
            self.connect()

    def close(self) -> None:
        """Close the session and stop the event loop thread (closing twice does nothing)."""
        try:
            self._drop_client()
        finally:
            self._loop_thread.stop(self.timeout_s)

    def __enter__(self) -> OpcUaLink:
        return self

    def __exit__(self, *exc) -> bool:
        self.close()
        return False

    # -- preflight and read-back ----------------------------------------------------------
    def read_attributes(self, node: str, names: tuple[str, ...]) -> list:
        """DataValues of attributes ``names`` of ``node`` (ConnectionError: lost; RafiUserError: refused)."""
        if not self.connected:
            raise ConnectionError(f"OPC UA {self.endpoint}: not connected")
        from asyncua import ua

        node_id = self.node_id(node)
        ids = [getattr(ua.AttributeIds, name) for name in names]
        try:
            return self._run(self._client.get_node(node_id).read_attributes(ids))
        except Exception as exc:
            fatal = self._fatal(exc, f"reading {node_id}")
            if fatal is not None:
                raise fatal from None
            raise self.lost(exc) from None

    def node_info(self, node: str) -> dict:
        """``exists``, ``datatype``, ``readable``, ``user_writable`` (``preflight.node_info``)."""
        from rafi.deploy.preflight import node_info

        return node_info(self, node)

    def read_value(self, node: str) -> float:
        """The number ``node`` holds now (:func:`rafi.deploy.preflight.read_value`)."""
        from rafi.deploy.preflight import read_value

        return read_value(self, node)
