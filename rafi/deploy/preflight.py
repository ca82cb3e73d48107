"""The preflight of ``rafi deploy``: what the controller must offer, checked before any write.

Run by :mod:`rafi.deploy.live_cli` after connecting and before the target is opened
(``docs/deploy.md``, "Preflight"). Every problem is one line naming the setting, the node, what
was found and what is expected; all of them are listed, not only the first. Standard library
only (``asyncua`` for the names of data types, when a link is there); the OPC UA reads go
through :class:`rafi.deploy.opcua_client.OpcUaLink`.

* every configured input node (``deploy.opcua.inputs``) exists, is readable by this session and
  holds a number (:data:`NUMERIC_TYPES`);
* every node the target writes exists, is a ``Double`` or ``Float`` (:data:`FLOAT_TYPES`), is
  readable (the read-back of the value the controller holds) and, unless a dry run, writable by
  this session's user (the ``CurrentWrite`` bit of its ``UserAccessLevel``).

The credentials and the model are checked earlier, before connecting
(:func:`rafi.deploy.live_cli.build`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from rafi.errors import TargetError

__all__ = ["FLOAT_TYPES", "NUMERIC_TYPES", "node_info", "preflight", "read_value"]

#: OPC UA data types an input may have (abstract numeric types included).
NUMERIC_TYPES = frozenset(
    "SByte Byte Int16 UInt16 Int32 UInt32 Int64 UInt64 Float Double Number Integer UInteger Decimal".split()
)
#: Data types that say only "some value": the value's own type decides (``BaseDataType``,
#: ``Number``; a server that declares none).
ABSTRACT_TYPES = (None, "BaseDataType", "Number")
#: Data types the compensation can be written as, exactly (:mod:`rafi.deploy.opcua_client`).
FLOAT_TYPES = ("Double", "Float")
_UNKNOWN = ("BadNodeIdUnknown", "BadNodeIdInvalid")


def _status(dv) -> str:
    code = getattr(dv, "StatusCode", None)
    return "Good" if code is None else code.name


def node_info(link, node: str) -> dict:
    """What the server says of ``node`` for ``link``'s session.

    Parameters
    ----------
    link : rafi.deploy.opcua_client.OpcUaLink
        Connected.
    node : str
        A node id or a name (``node_prefix`` is put before it).

    Returns
    -------
    dict
        ``node_id`` (complete), ``exists`` (False: the server has no such node), ``datatype``
        (the OPC UA name of its data type, ``Double``, ``Int16``...; ``ns=N;i=M`` for a type of
        the server's own; None if it has none), ``readable`` and ``user_writable`` (the
        ``CurrentRead`` / ``CurrentWrite`` bits of both ``AccessLevel`` and this session's
        ``UserAccessLevel``).

    Raises
    ------
    ConnectionError
        The connection is lost.
    """
    from asyncua import ua

    node_id = link.node_id(node)
    values = link.read_attributes(node, ("DataType", "AccessLevel", "UserAccessLevel"))
    if _status(values[0]) in _UNKNOWN:
        return dict(node_id=node_id, exists=False, datatype=None, readable=False, user_writable=False)
    datatype = None
    if _status(values[0]) == "Good" and values[0].Value is not None:
        type_id = values[0].Value.Value
        standard = type_id.NamespaceIndex == 0 and type_id.Identifier in ua.ObjectIdNames
        datatype = ua.ObjectIdNames[type_id.Identifier] if standard else type_id.to_string()

    def bits(dv) -> int:
        value = dv.Value.Value if _status(dv) == "Good" and dv.Value is not None else None
        return int(value) if isinstance(value, int) else 0

    access = bits(values[1]) & bits(values[2])
    return {
        "node_id": node_id,
        "exists": True,
        "datatype": datatype,
        "readable": bool(access & 1),  # bit 0: CurrentRead
        "user_writable": bool(access & 2),  # bit 1: CurrentWrite
    }


def read_value(link, node: str) -> float:
    """The finite number ``node`` holds now (the read-back of the SINUMERIK target).

    Raises
    ------
    ConnectionError
        The connection is lost.
    TargetError
        No good finite number in the node: where the controller is cannot be known, so nothing
        may be written (exit status 65, as a value outside ``deploy.clamp_um``).
    RafiUserError
        The server refuses the read (no such node, no right to read).
    """
    (dv,) = link.read_attributes(node, ("Value",))
    raw = dv.Value.Value if _status(dv) == "Good" and dv.Value is not None else None
    try:
        value = float(raw)
    except (TypeError, ValueError):
        value = math.nan
    if not math.isfinite(value):
        raise TargetError(
            f"OPC UA node {link.node_id(node)} holds no finite number ({_status(dv)}, {raw!r}): where "
            "the controller is cannot be known, so nothing is written"
        )
    return value


def _input_problems(name: str, info: dict, who: str) -> list[str]:
    where = f"deploy.opcua.inputs.{name}: node {info['node_id']}"
    if not info["exists"]:
        return [f"{where}: the server has no such node (check the name and the namespace)"]
    out = []
    if info["datatype"] not in NUMERIC_TYPES:
        out.append(f"{where} is of type {info['datatype']}; expected a number (Double, Float, Int16, ...)")
    if not info["readable"]:
        out.append(f"{where} is not readable for {who}")
    return out


def _output_problems(info: dict, who: str, write: bool) -> list[str]:
    where = f"deploy.target: node {info['node_id']}"
    if not info["exists"]:
        return [f"{where}: the server has no such node (check deploy.target.node_template and axis.number)"]
    out = []
    if info["datatype"] not in FLOAT_TYPES:
        out.append(
            f"{where} is of type {info['datatype']}; the compensation is written as Double or Float "
            "(the setting data SD 43900/43910/43920 are Double)"
        )
    if not info["readable"]:
        out.append(f"{where} is not readable for {who} (needed to start from the value it holds)")
    if write and not info["user_writable"]:
        out.append(
            f"{where} is not writable for {who} (its UserAccessLevel lacks CurrentWrite; SINUMERIK: "
            "the user needs the SeaWrite right)"
        )
    return out


def preflight(
    link, *, inputs: Mapping[str, str], outputs: Sequence[str], write: bool, user: str | None = None
) -> list[str]:
    """Every problem of the nodes ``rafi deploy`` reads and writes, one line each.

    Parameters
    ----------
    link : rafi.deploy.opcua_client.OpcUaLink
        Connected.
    inputs : mapping of str to str
        Input name (``speed_rpm``, ``T1``..) -> node id (``deploy.opcua.inputs``); empty when
        the inputs come from a followed log.
    outputs : sequence of str
        The nodes the target writes (:meth:`SinumerikTarget.output_nodes`); empty for a file
        target.
    write : bool
        The target will write (not a dry run): this session's user must be allowed to.
    user : str, optional
        The session's user name, for the messages (None: anonymous).

    Returns
    -------
    list of str
        The problems (empty: go). Each is a settings mistake (exit status 64).

    Raises
    ------
    ConnectionError
        The connection is lost meanwhile (exit status 69).
    """
    who = f"user {user!r}" if user else "an anonymous session"
    problems = []
    for name, node in inputs.items():
        problems += _input_problems(name, link.node_info(node), who)
    for node in outputs:
        info = link.node_info(node)
        if info["exists"] and info["datatype"] in ABSTRACT_TYPES:
            info = dict(info, datatype=_value_type(link, node))
        problems += _output_problems(info, who, write)
    return problems


def _value_type(link, node: str) -> str | None:
    """The variant type of the value ``node`` holds (a node declared with an abstract data type
    is written as its value's type, as :meth:`OpcUaLink.write_value` does)."""
    (dv,) = link.read_attributes(node, ("Value",))
    variant = dv.Value if _status(dv) == "Good" else None
    return getattr(getattr(variant, "VariantType", None), "name", None)
