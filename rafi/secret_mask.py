"""Secrets are never printed: credentials written into ``config.yaml`` are found and masked.

Credentials never belong in ``config.yaml`` (``rafi deploy`` and ``rafi record`` refuse a config
that holds one, :func:`rafi.deploy.opcua_client.opcua_settings`); a user may still write one
there. Every command that prints settings or a message quoting them masks them first:

* a value under a credentials key (:data:`rafi.deploy.opcua_credentials.SECRET_KEYS`, any case,
  at any depth): ``password: hunter2`` is shown as ``password: '***'``;
* the user information of a URL (``opc.tcp://bob:hunter2@host:4840``): ``opc.tcp://***@host:4840``.

:func:`secret_paths` names where they are (for the one-line refusal), :func:`masked` returns a
copy to print, :func:`scrub` removes their values from a message (a schema error quoting a block).
Standard library only.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from rafi.deploy.opcua_credentials import SECRET_KEYS

__all__ = ["MASK", "masked", "scrub", "secret_paths"]

#: What is printed instead of a secret.
MASK = "***"
_USERINFO = re.compile(r"^([a-zA-Z][a-zA-Z0-9+.-]*://)([^/@]+)@")


def _walk(tree, path: tuple):
    """``(path, value, is_secret_key)`` of every leaf of ``tree`` (mappings and lists)."""
    if isinstance(tree, Mapping):
        for key, value in tree.items():
            if _is_secret(key, value):
                yield (*path, str(key)), value, True
            else:
                yield from _walk(value, (*path, str(key)))
    elif isinstance(tree, list):
        for i, value in enumerate(tree):
            yield from _walk(value, (*path, str(i)))
    else:
        yield path, tree, False


def secret_paths(tree) -> list[str]:
    """Where ``tree`` (``config.yaml`` as loaded, or a part of it) holds a secret.

    Parameters
    ----------
    tree : mapping or list
        Settings as loaded from YAML.

    Returns
    -------
    list of str
        Dotted paths (``machines.m1.deploy.opcua.password``), in the tree's order.
    """
    return [
        ".".join(path)
        for path, value, secret in _walk(tree, ())
        if secret or (isinstance(value, str) and _USERINFO.match(value))
    ]


def _secret_values(tree) -> list[str]:
    out = []
    for _, value, secret in _walk(tree, ()):
        if secret:
            out.append(str(value))
        elif isinstance(value, str) and (match := _USERINFO.match(value)):
            out.extend(part for part in match.group(2).split(":") if part)
    return sorted(set(out), key=len, reverse=True)


def _is_secret(key, value) -> bool:
    """A set value (not a block, not empty) under a credentials key."""
    leaf = not isinstance(value, (Mapping, list)) and value not in (None, "")
    return leaf and str(key).lower() in SECRET_KEYS


def masked(tree):
    """A copy of ``tree`` with every secret replaced by :data:`MASK` (module docstring)."""
    if isinstance(tree, Mapping):
        return {key: MASK if _is_secret(key, value) else masked(value) for key, value in tree.items()}
    if isinstance(tree, list):
        return [masked(value) for value in tree]
    if isinstance(tree, str):
        return _USERINFO.sub(lambda m: m.group(1) + MASK + "@", tree)
    return tree


def scrub(text: str, tree) -> str:
    """``text`` with every secret value of ``tree`` replaced by :data:`MASK`."""
    for value in _secret_values(tree):
        text = text.replace(value, MASK)
    return text
