"""Where the OPC UA user and password of ``rafi deploy`` come from: never ``config.yaml``.

* :func:`load_credentials` - the environment (``RAFI_OPCUA_USER`` / ``RAFI_OPCUA_PASSWORD``),
  else a credentials file (named by ``RAFI_OPCUA_CREDENTIALS`` or
  ``deploy.opcua.credentials_file``) outside the project, readable by its owner only; else an
  anonymous session.
* :func:`require_credentials` - refuses an anonymous session *before connecting* when the
  target writes to the controller (an anonymous session may read, not write).

``docs/deploy.md`` ("Credentials") describes both for a controls engineer. Standard library only.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Mapping
from pathlib import Path

from rafi.errors import RafiUserError, short_path

__all__ = [
    "ENV_CREDENTIALS",
    "ENV_PASSWORD",
    "ENV_USER",
    "SECRET_KEYS",
    "load_credentials",
    "repository_root",
    "require_credentials",
]

ENV_USER = "RAFI_OPCUA_USER"
ENV_PASSWORD = "RAFI_OPCUA_PASSWORD"
ENV_CREDENTIALS = "RAFI_OPCUA_CREDENTIALS"

#: Keys refused in ``deploy.opcua``: credentials never go to config.yaml.
SECRET_KEYS = ("user", "username", "user_name", "login", "password", "passwd", "pwd", "secret", "token")

#: What a credentials file holds and where it goes, for the messages.
_HOW = (
    "two lines 'user: NAME' and 'password: SECRET', outside the project, chmod 600 "
    "(docs/deploy.md#credentials)"
)


def repository_root(start: Path) -> Path | None:
    """The nearest folder at or above ``start`` holding ``.git``, else None."""
    for folder in (start, *start.parents):
        if (folder / ".git").exists():
            return folder
    return None


def refuse_inside_project(real: Path, project_dir: Path, where: str, example: str) -> None:
    """RafiUserError if ``real`` (resolved) lies in the project folder or its git repository:
    a secret there ends up in a commit, a copy or a backup of the project."""
    forbidden = [project_dir.resolve()]
    repo = repository_root(project_dir.resolve())
    if repo is not None:
        forbidden.append(repo)
    for root in forbidden:
        if real == root or root in real.parents:
            raise RafiUserError(
                f"{where} lies inside {short_path(root)} (the project or its repository); keep "
                f"it outside (e.g. {example}, mode 600)"
            )


def _read_credentials_file(path: Path, project_dir: Path, named_by: str) -> tuple[str, str]:
    where = f"credentials file {short_path(path)} (named by {named_by})"
    try:
        real = path.resolve(strict=True)
    except (OSError, RuntimeError):
        raise RafiUserError(f"{where} does not exist: create it with {_HOW}") from None
    refuse_inside_project(real, project_dir, where, "/etc/rafi/opcua.credentials")
    mode = real.stat().st_mode
    if not stat.S_ISREG(mode):
        raise RafiUserError(f"{where} is not a regular file: it should hold {_HOW}")
    if mode & 0o077:
        raise RafiUserError(
            f"{where} has mode {stat.S_IMODE(mode):o}: readable or writable by group or others; "
            f"allow its owner only (chmod 600 {short_path(real)})"
        )
    values = {}
    for number, line in enumerate(real.read_text(encoding="utf-8").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        key, sep, value = line.partition("=") if "=" in line.split(":", 1)[0] else line.partition(":")
        if not sep or key.strip() not in ("user", "password"):
            raise RafiUserError(f"{where}, line {number}: expected 'user: NAME' or 'password: SECRET'")
        values[key.strip()] = value.strip()
    if not values.get("user") or "password" not in values:
        raise RafiUserError(f"{where}: needs a line 'user: NAME' and a line 'password: SECRET'")
    return values["user"], values["password"]


def load_credentials(
    settings: Mapping, *, project_dir=".", environ: Mapping[str, str] | None = None
) -> tuple[str | None, str | None]:
    """The user and password of the OPC UA session, never from ``config.yaml``.

    In this order: the environment variables ``RAFI_OPCUA_USER`` and ``RAFI_OPCUA_PASSWORD``
    (both, or neither); the file named by ``RAFI_OPCUA_CREDENTIALS``; the file named by
    ``deploy.opcua.credentials_file``; else anonymous (``(None, None)``: a SINUMERIK then lets
    the client read but not write).

    The file holds two lines, ``user: NAME`` and ``password: SECRET`` (``#`` comments allowed).
    It must lie outside the project folder and its git repository, and be readable by its owner
    only (like ssh, a file any group or other may read is refused).

    Parameters
    ----------
    settings : mapping
        :func:`rafi.deploy.opcua_client.opcua_settings`.
    project_dir : path
        The folder of ``config.yaml``.
    environ : mapping, optional
        The environment (default ``os.environ``).

    Raises
    ------
    RafiUserError
        Only one of the two variables set; the file missing (the message names the variable or
        setting that named it, and what the file must hold), inside the project, too open, or
        malformed.
    """
    env = os.environ if environ is None else environ
    user, password = env.get(ENV_USER), env.get(ENV_PASSWORD)
    if user or password:
        if not user or password is None:
            raise RafiUserError(f"set both {ENV_USER} and {ENV_PASSWORD}, or neither")
        return user, password
    if env.get(ENV_CREDENTIALS):
        path, named_by = env[ENV_CREDENTIALS], f"the environment variable {ENV_CREDENTIALS}"
    else:
        path, named_by = settings.get("credentials_file"), "deploy.opcua.credentials_file"
    if path:
        return _read_credentials_file(Path(os.path.expanduser(path)), Path(project_dir), named_by)
    return None, None


def require_credentials(user: str | None, settings: Mapping | None = None) -> None:
    """Refuse an anonymous session for a target that writes to the controller, before connecting.

    Call it when the target writes over OPC UA (the ``sinumerik`` target, not ``--dry-run``):
    an anonymous session may read but not write (a SINUMERIK refuses with
    ``BadUserAccessDenied``), so without a user the run would only fail at its first write.

    Parameters
    ----------
    user : str or None
        From :func:`load_credentials` (None: no credentials were found).
    settings : mapping, optional
        :func:`rafi.deploy.opcua_client.opcua_settings`, to name the configured file.

    Raises
    ------
    RafiUserError
        (exit 64) No user: the message says where credentials are looked for and what to do.
    """
    if user:
        return
    named = (settings or {}).get("credentials_file")
    file_setting = f"is {named}" if named else "is not set"
    looked = (
        f"{ENV_USER}/{ENV_PASSWORD} are not set, {ENV_CREDENTIALS} is not set, "
        f"deploy.opcua.credentials_file {file_setting}"
    )
    raise RafiUserError(
        "the sinumerik target writes to the controller, but no OPC UA user is configured "
        f"(an anonymous session may only read): {looked}; set the two variables or name a "
        f"credentials file holding {_HOW}; --dry-run needs none"
    )
