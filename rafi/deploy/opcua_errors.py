"""What an OPC UA server's refusal means, in one line (the link of ``rafi deploy`` / ``rafi record``).

:func:`refusal` turns an asyncua error whose status no reconnecting cures (a login, a right, a
node, a certificate, an unencrypted session the server does not accept) into a
:class:`rafi.errors.RafiUserError` naming what to do; any other error is a lost or failed
connection, for the caller to retry. :mod:`rafi.deploy.opcua_client` uses it; ``docs/deploy.md``
("Security", "When the server goes away") lists the messages. Standard library only (asyncua's
status names are looked up only when one is met).
"""

from __future__ import annotations

import re

from rafi.deploy.opcua_credentials import ENV_PASSWORD, ENV_USER
from rafi.errors import RafiUserError

__all__ = ["FATAL", "UNENCRYPTED_REFUSED", "refusal", "status_name"]

#: Status codes that no reconnecting cures: the loop stops with a message.
FATAL = {
    "BadUserAccessDenied": "the server refused the user (wrong user or password, or no right to do this)",
    "BadIdentityTokenRejected": "the server does not accept this kind of login (anonymous or user/password)",
    "BadIdentityTokenInvalid": "the server refused the login",
    "BadNotWritable": "the node is not writable for this user (SINUMERIK: the user needs the SeaWrite right)",
    "BadWriteNotSupported": "the server refused the write's form (data type or timestamps)",
    "BadTypeMismatch": "the value's data type is not the node's",
    "BadNodeIdUnknown": "the server has no such node",
    "BadNodeIdInvalid": "the node id is not valid",
}

#: The statuses of a server that refuses a session without security (no certificate involved).
UNENCRYPTED_REFUSED = ("BadSecurityModeRejected", "BadSecurityPolicyRejected")
#: asyncua's own refusal to log in when the server lists no endpoint of security policy None.
_NO_PLAIN_ENDPOINT = re.compile(r"^No matching endpoints: .*#None$")


def status_name(exc: BaseException) -> str | None:
    """The OPC UA status name of an asyncua error (``BadUserAccessDenied``), else None.

    Parameters
    ----------
    exc : BaseException
        What a call of asyncua raised.

    Returns
    -------
    str or None
        The status's name; the exception's class name for a code asyncua does not know; None
        for an error without a status (a socket's, a timeout).
    """
    code = getattr(exc, "code", None)
    if code is None:
        return None
    try:
        from asyncua.ua.status_codes import get_name_and_doc

        return get_name_and_doc(code)[0]
    except (ImportError, KeyError, TypeError):
        return type(exc).__name__


def refusal(
    exc: BaseException, what: str, *, endpoint: str, user: str | None, certificate: str | None, secure: bool
) -> RafiUserError | None:
    """The one-line error of a refusal that reconnecting cannot cure, else None.

    Parameters
    ----------
    exc : BaseException
        What asyncua raised.
    what : str
        What was refused, as the subject of "... was refused": ``"the login"``,
        ``"writing ns=2;s=..."``, ``"reading the inputs"``.
    endpoint : str
        ``deploy.opcua.endpoint``.
    user : str or None
        The user name (None: an anonymous session).
    certificate : str or None
        ``deploy.opcua.certificate`` (None: none configured).
    secure : bool
        A security policy is configured (``deploy.opcua.security_policy``).

    Returns
    -------
    RafiUserError or None
        None: not a refusal of this kind (a lost connection, to retry).
    """
    name = status_name(exc)
    text = str(exc)
    if not secure and (name in UNENCRYPTED_REFUSED or _NO_PLAIN_ENDPOINT.match(text)):
        why = name or "it offers no endpoint without security"
        return RafiUserError(
            f"OPC UA {endpoint}: the server refuses unencrypted sessions ({why}): set "
            "deploy.opcua.security_policy and security_mode, a client certificate (rafi certificate) "
            "and whom to trust (docs/deploy.md#security)"
        )
    if name is None:
        return None
    if name.startswith(("BadCertificate", "BadSecurity")):
        return RafiUserError(
            f"OPC UA {endpoint}: the server refused the client's certificate "
            f"{certificate or '(none)'}: {name}: make the server trust it, or check "
            "deploy.opcua.security_policy and security_mode (docs/deploy.md#security)"
        )
    if name in FATAL:
        who = f"user {user!r}" if user else "an anonymous session"
        return RafiUserError(
            f"OPC UA {endpoint}: {what} was refused for {who}: {name}: {FATAL[name]}. "
            f"Credentials come from {ENV_USER}/{ENV_PASSWORD} or a credentials file (docs/deploy.md)"
        )
    return None
