"""OPC UA security of ``rafi deploy``: signed and encrypted sessions, and whom to trust.

``docs/deploy.md`` ("Security") describes the settings for a controls engineer. The keys
(``security_policy``, ``security_mode``, ``certificate``, ``private_key``,
``server_certificate``, ``trust_dir``, ``server_fingerprint``, ``allow_insecure``) and their
defaults are :data:`rafi.deploy.opcua_client.OPCUA_DEFAULTS`; this module checks them and uses
asyncua's own machinery (``Client.set_security``, ``asyncua.crypto.truststore.TrustStore``,
``asyncua.crypto.validator.CertificateValidator``), no cryptography of its own.

* :func:`check_security_settings` - the settings, checked (part of ``opcua_settings``).
* :func:`load_security` - the client's certificate and key read and checked before connecting.
* :func:`plaintext_notice` - a password over an unencrypted channel is refused, unless
  ``allow_insecure: true``, which gives a warning line at every start.
* :func:`secure_client` - before a secure session: ask the server for its endpoints (over the
  unsecured discovery channel, which carries no secret), check the server's certificate
  (:func:`check_server_certificate`: valid now, and the pinned one / the fingerprint / trusted
  by ``trust_dir``), then ``set_security`` with exactly that certificate. Nothing is ever
  trusted on first use.

asyncua and cryptography are imported only when used (the ``deploy`` extra).
"""

from __future__ import annotations

import hashlib
import os
import re
import stat
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from rafi.errors import SettingsError, UntrustedCertificate, short_path, shorten

__all__ = [
    "MODES",
    "POLICIES",
    "ClientSecurity",
    "certificate_summary",
    "check_security_settings",
    "check_server_certificate",
    "fingerprint",
    "load_security",
    "plaintext_notice",
    "secure_client",
]

#: Security policy (the OPC UA name, as a server lists it) -> asyncua's class.
POLICIES = {
    "Basic256Sha256": "SecurityPolicyBasic256Sha256",
    "Aes128_Sha256_RsaOaep": "SecurityPolicyAes128Sha256RsaOaep",
    "Aes256_Sha256_RsaPss": "SecurityPolicyAes256Sha256RsaPss",
}
MODES = ("Sign", "SignAndEncrypt")
_PATH_KEYS = ("certificate", "private_key", "server_certificate", "trust_dir")
_TRUST_KEYS = ("server_certificate", "trust_dir", "server_fingerprint")
_DOCS = "docs/deploy.md#security"


def fingerprint(der: bytes) -> str:
    """SHA-256 of a DER certificate as ``AB:CD:...`` (as openssl and most HMIs show it)."""
    digest = hashlib.sha256(der).hexdigest().upper()
    return ":".join(digest[i : i + 2] for i in range(0, len(digest), 2))


def certificate_summary(cert) -> str:
    """``subject 'CN=...', SHA-256 AB:..`` of an ``x509.Certificate``, for a message."""
    from cryptography.hazmat.primitives.serialization import Encoding

    subject = shorten(cert.subject.rfc4514_string() or "(empty)", 80)
    return f"subject '{subject}', SHA-256 {fingerprint(cert.public_bytes(Encoding.DER))}"


# --------------------------------------------------------------------------- settings


def _policy_name(value) -> str | None:
    if value is None or (isinstance(value, str) and value.strip().lower() in ("none", "")):
        return None
    wanted = str(value).replace("_", "").lower() if isinstance(value, str) else None
    for name in POLICIES:
        if name.replace("_", "").lower() == wanted:
            return name
    raise SettingsError(f"deploy.opcua.security_policy is {value!r}; expected none, {', '.join(POLICIES)}")


def _path(out: dict, key: str, project_dir: Path) -> Path | None:
    value = out[key]
    if value is None:
        return None
    if not isinstance(value, str) or not value.strip():
        raise SettingsError(f"deploy.opcua.{key} is {value!r}; expected a path")
    path = Path(os.path.expanduser(value.strip()))
    return path if path.is_absolute() else project_dir / path


def check_security_settings(out: dict, project_dir=".") -> dict:
    """The security keys of ``out`` (``deploy.opcua`` with defaults) checked in place.

    ``security_policy`` becomes its OPC UA name or None, the paths absolute (a relative one is
    taken from ``project_dir``), ``server_fingerprint`` 64 lower-case hex digits.

    Raises
    ------
    SettingsError
        An unknown policy or mode; a security key without ``security_policy``; a policy without
        ``certificate`` / ``private_key``, or with nothing to trust the server by (never
        trusted on first use); a private key inside the project; a malformed fingerprint.
    """
    from rafi.deploy.opcua_credentials import refuse_inside_project

    project_dir = Path(project_dir)
    out["security_policy"] = policy = _policy_name(out["security_policy"])
    if out["security_mode"] not in MODES:
        raise SettingsError(
            f"deploy.opcua.security_mode is {out['security_mode']!r}; expected Sign or SignAndEncrypt"
        )
    if not isinstance(out["allow_insecure"], bool):
        raise SettingsError(
            f"deploy.opcua.allow_insecure is {out['allow_insecure']!r}; expected true or false"
        )
    for key in _PATH_KEYS:
        out[key] = _path(out, key, project_dir)
    pin = out["server_fingerprint"]
    if pin is not None:
        digits = re.sub(r"[\s:]", "", str(pin)).lower()
        if not re.fullmatch(r"[0-9a-f]{64}", digits):
            raise SettingsError(
                f"deploy.opcua.server_fingerprint is {shorten(str(pin), 110)!r}; expected the SHA-256 of the "
                "server's certificate: 64 hex digits, colons allowed"
            )
        out["server_fingerprint"] = digits
    if policy is None:
        extra = [k for k in (*_PATH_KEYS, "server_fingerprint") if out[k] is not None]
        if extra:
            raise SettingsError(
                f"deploy.opcua.{extra[0]} is set but security_policy is none, so nothing reads it: set "
                f"security_policy ({' or '.join(POLICIES)}) or remove it ({_DOCS})"
            )
        return out
    for key in ("certificate", "private_key"):
        if out[key] is None:
            raise SettingsError(
                f"deploy.opcua.security_policy is {policy} but deploy.opcua.{key} is not set: the client "
                f"needs its certificate and private key (create them with `rafi certificate`, {_DOCS})"
            )
    if all(out[k] is None for k in _TRUST_KEYS):
        raise SettingsError(
            f"deploy.opcua.security_policy is {policy} but nothing says which server certificate to "
            "trust: set server_fingerprint (its SHA-256), server_certificate (its file) or trust_dir (a "
            f"folder of trusted certificates); rafi never trusts a server on first use ({_DOCS})"
        )
    where = f"deploy.opcua.private_key {short_path(out['private_key'])}"
    refuse_inside_project(out["private_key"].resolve(), project_dir, where, "/etc/rafi/pki/rafi.key")
    return out


# --------------------------------------------------------------------------- files


@dataclass(frozen=True)
class ClientSecurity:
    """What :func:`secure_client` needs, read and checked before connecting."""

    policy: str  # a key of POLICIES
    mode: str  # Sign or SignAndEncrypt
    certificate_der: bytes
    private_key_der: bytes  # PKCS8, unencrypted
    application_uri: str  # the client's, from its certificate
    pinned_der: bytes | None
    pinned_path: Path | None
    fingerprint: str | None  # 64 lower-case hex digits
    trust_dir: Path | None
    allow_insecure: bool


def _read(path: Path, key: str) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        missing = isinstance(exc, FileNotFoundError)
        reason = "does not exist" if missing else f"cannot be read ({exc.strerror})"
        raise SettingsError(
            f"deploy.opcua.{key} {short_path(path)} {reason} (create the client's files with `rafi "
            f"certificate`, {_DOCS})"
        ) from None


def _certificate(path: Path, key: str):
    from cryptography import x509

    data = _read(path, key)
    try:
        if b"-----BEGIN" in data:
            return x509.load_pem_x509_certificate(data)
        return x509.load_der_x509_certificate(data)
    except ValueError:
        raise SettingsError(
            f"deploy.opcua.{key} {short_path(path)} is not a certificate (PEM or DER)"
        ) from None


def _private_key(path: Path):
    from cryptography.hazmat.primitives import serialization

    data = _read(path, "private_key")
    mode = path.stat().st_mode
    if mode & 0o077:
        raise SettingsError(
            f"deploy.opcua.private_key {short_path(path)} has mode {stat.S_IMODE(mode):o}: readable or "
            f"writable by group or others; allow its owner only (chmod 600 {short_path(path)})"
        )
    load = serialization.load_pem_private_key if b"-----BEGIN" in data else serialization.load_der_private_key
    try:
        return load(data, password=None)
    except TypeError:
        raise SettingsError(
            f"deploy.opcua.private_key {short_path(path)} is protected by a passphrase; rafi needs an "
            "unencrypted key readable by its owner only (openssl pkey -in KEY -out NEW)"
        ) from None
    except ValueError:
        raise SettingsError(
            f"deploy.opcua.private_key {short_path(path)} is not a private key (PEM or DER)"
        ) from None


def _validity_problem(cert, now: datetime) -> str | None:
    if now > cert.not_valid_after_utc:
        return f"expired on {cert.not_valid_after_utc:%Y-%m-%d %H:%M} UTC"
    if now < cert.not_valid_before_utc:
        return (
            f"is not valid before {cert.not_valid_before_utc:%Y-%m-%d %H:%M} UTC (check the clocks of "
            "this computer and of its issuer)"
        )
    return None


def load_security(settings, *, now: datetime | None = None) -> ClientSecurity | None:
    """The client's certificate and key and the trust settings; None without a security policy.

    Raises
    ------
    SettingsError
        A file missing or unreadable, not a certificate or key; the key readable by others,
        protected by a passphrase or not the certificate's; the client's certificate not valid
        now or without an application URI (a ``subjectAltName`` URI, which servers require);
        ``trust_dir`` not a folder or without certificates.
    """
    if settings.get("security_policy") is None:
        return None
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    now = now or datetime.now(UTC)
    path = settings["certificate"]
    cert = _certificate(path, "certificate")
    key = _private_key(settings["private_key"])
    der = serialization.Encoding.DER
    if cert.public_key().public_bytes(der, serialization.PublicFormat.SubjectPublicKeyInfo) != (
        key.public_key().public_bytes(der, serialization.PublicFormat.SubjectPublicKeyInfo)
    ):
        raise SettingsError(
            f"deploy.opcua.private_key {short_path(settings['private_key'])} is not the key of "
            f"deploy.opcua.certificate {short_path(path)}"
        )
    problem = _validity_problem(cert, now)
    if problem:
        raise SettingsError(
            f"deploy.opcua.certificate {short_path(path)} {problem}: create a new one (`rafi certificate "
            "--force`) and have the server trust it"
        )
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        uris = san.get_values_for_type(x509.UniformResourceIdentifier)
    except x509.ExtensionNotFound:
        uris = []
    if not uris:
        raise SettingsError(
            f"deploy.opcua.certificate {short_path(path)} has no application URI (a subjectAltName URI): "
            f"OPC UA servers refuse such a client; create one with `rafi certificate` ({_DOCS})"
        )
    trust_dir = settings["trust_dir"]
    if trust_dir is not None:
        if not trust_dir.is_dir():
            raise SettingsError(f"deploy.opcua.trust_dir {short_path(trust_dir)} is not a folder")
        if not any(p.suffix.lower() in (".der", ".pem") for p in trust_dir.iterdir()):
            raise SettingsError(
                f"deploy.opcua.trust_dir {short_path(trust_dir)} holds no certificate (*.der, *.pem): "
                "put the server's certificate or its issuer's there"
            )
    pinned = settings["server_certificate"]
    return ClientSecurity(
        policy=settings["security_policy"],
        mode=settings["security_mode"],
        certificate_der=cert.public_bytes(der),
        private_key_der=key.private_bytes(
            der, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        ),
        application_uri=uris[0],
        pinned_der=None if pinned is None else _certificate(pinned, "server_certificate").public_bytes(der),
        pinned_path=pinned,
        fingerprint=settings["server_fingerprint"],
        trust_dir=trust_dir,
        allow_insecure=settings["allow_insecure"],
    )


# --------------------------------------------------------------------------- plain text


def plaintext_notice(settings, user: str | None) -> str | None:
    """The warning to log at every start, or None; refuses a password sent as plain text.

    Without a security policy a password crosses the network readable by anyone on it:
    refused unless ``allow_insecure: true``, which is then said at every start (and so is an
    anonymous unencrypted session under ``allow_insecure``).

    Raises
    ------
    SettingsError
        A user with ``security_policy: none`` and ``allow_insecure`` false.
    """
    if settings.get("security_policy") is not None:
        return None
    endpoint = settings["endpoint"]
    if user:
        if not settings.get("allow_insecure"):
            raise SettingsError(
                f"deploy.opcua: the password of user {user!r} would cross the network unencrypted "
                f"(security_policy is none): set security_policy and the certificates ({_DOCS}), or "
                "accept plain text with allow_insecure: true"
            )
        return (
            f"OPC UA {endpoint}: WARNING allow_insecure: the password of user {user!r} is sent "
            "unencrypted (security_policy: none); anyone on this network can read it"
        )
    if settings.get("allow_insecure"):
        return (
            f"OPC UA {endpoint}: WARNING allow_insecure: the session is neither signed nor encrypted "
            "(security_policy: none); anonymous, so no password is sent"
        )
    return None


# --------------------------------------------------------------------------- the session


async def check_server_certificate(cert, security: ClientSecurity, endpoint: str, *, now=None) -> None:
    """Refuse the server's certificate unless it is valid now and passes every configured check:
    the pinned certificate, the fingerprint, trusted by ``trust_dir`` (itself or its issuer,
    asyncua's ``TrustStore`` and ``CertificateValidator``).

    Raises
    ------
    UntrustedCertificate
        (exit 64) One line: which certificate (subject, SHA-256), why, and what to do.
    """
    from cryptography.hazmat.primitives.serialization import Encoding

    der = cert.public_bytes(Encoding.DER)
    who = f"OPC UA {endpoint}: the server's certificate ({certificate_summary(cert)})"
    problem = _validity_problem(cert, now or datetime.now(UTC))
    if problem:
        raise UntrustedCertificate(
            f"{who} {problem}: refused; renew it on the server, then trust the new one"
        )
    if security.fingerprint is not None and hashlib.sha256(der).hexdigest() != security.fingerprint:
        raise UntrustedCertificate(
            f"{who} is not the one deploy.opcua.server_fingerprint names: refused; if the server's "
            "certificate was renewed, compare this fingerprint with the controller's and set it"
        )
    if security.pinned_der is not None and der != security.pinned_der:
        raise UntrustedCertificate(
            f"{who} differs from deploy.opcua.server_certificate {short_path(security.pinned_path)}: "
            "refused; if the server's certificate was renewed, compare the fingerprint and replace the file"
        )
    if security.trust_dir is not None:
        from asyncua import ua
        from asyncua.common.utils import ServiceError
        from asyncua.crypto.truststore import TrustStore
        from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

        store = TrustStore([security.trust_dir], [])
        try:
            await store.load_trust()
        except ValueError as exc:
            raise SettingsError(
                f"deploy.opcua.trust_dir {short_path(security.trust_dir)} holds a file that is not a "
                f"certificate ({shorten(str(exc), 80)})"
            ) from None
        options = CertificateValidatorOptions.TRUSTED | CertificateValidatorOptions.PEER_SERVER
        try:
            await CertificateValidator(options, store)(cert, ua.ApplicationDescription())
        except ServiceError as exc:
            name = ua.StatusCode(exc.code).name
            if name != "BadCertificateUntrusted":
                raise UntrustedCertificate(f"{who} is refused by asyncua's check: {name}") from None
            raise UntrustedCertificate(
                f"{who} is not trusted by deploy.opcua.trust_dir {short_path(security.trust_dir)}: refused; "
                "if it is your controller's (compare the fingerprint with its HMI), copy it there"
            ) from None


async def secure_client(client, security: ClientSecurity, endpoint: str, user: str | None, log) -> None:
    """Make ``client`` (an ``asyncua.Client``, not connected) use ``security`` with the server's
    certificate checked first (:func:`check_server_certificate`).

    Raises
    ------
    SettingsError
        The server offers no endpoint with this policy and mode; a password would go as plain
        text over a signed-only channel (unless ``allow_insecure``).
    UntrustedCertificate
        The server's certificate is refused.
    """
    from asyncua import ua
    from asyncua.crypto import security_policies, uacrypto

    client.application_uri = security.application_uri
    policy = getattr(security_policies, POLICIES[security.policy])
    mode = getattr(ua.MessageSecurityMode, security.mode)
    endpoints = await client.connect_and_get_server_endpoints()
    matching = [e for e in endpoints if e.SecurityPolicyUri == policy.URI and e.SecurityMode == mode]
    if not matching:
        offered = sorted(
            {f"{e.SecurityPolicyUri.rsplit('#', 1)[-1]}/{e.SecurityMode.name.rstrip('_')}" for e in endpoints}
        )
        raise SettingsError(
            f"OPC UA {endpoint}: the server offers no endpoint {security.policy}/{security.mode}; it "
            f"offers {', '.join(offered)}: set deploy.opcua.security_policy and security_mode to one of them"
        )
    server_cert = uacrypto.x509_from_der(matching[0].ServerCertificate)
    if server_cert is None:
        raise UntrustedCertificate(f"OPC UA {endpoint}: the server sends no certificate: refused")
    await check_server_certificate(server_cert, security, endpoint)
    if user and mode == ua.MessageSecurityMode.Sign:
        tokens = [t for t in matching[0].UserIdentityTokens if t.TokenType == ua.UserTokenType.UserName]
        if tokens and tokens[0].SecurityPolicyUri in (None, "", security_policies.SecurityPolicyNone.URI):
            if not security.allow_insecure:
                raise SettingsError(
                    f"OPC UA {endpoint}: the server takes the password unencrypted on a Sign-only channel: "
                    "set deploy.opcua.security_mode: SignAndEncrypt (or allow_insecure: true)"
                )
            log(f"OPC UA {endpoint}: WARNING allow_insecure: the password is sent unencrypted (Sign only)")
    from cryptography.hazmat.primitives.serialization import Encoding

    await client.set_security(
        policy,
        uacrypto.CertProperties(security.certificate_der),
        uacrypto.CertProperties(security.private_key_der),
        server_certificate=uacrypto.CertProperties(server_cert.public_bytes(Encoding.DER)),
        mode=mode,
    )
