"""The documented error types, and the bound on what a message may quote.

* :class:`RafiUserError` - the common base of the errors a *user* can cause and cure (a bad
  file, a bad ``config.yaml``): the workflow prints its message as one line (the traceback
  goes to the rule's log), and ``rafi`` exits with its :attr:`~RafiUserError.exit_status`
  (``EX_USAGE`` 64 for configuration, ``EX_DATAERR`` 65 for bad data) instead of printing a
  traceback; ``rafi --debug`` / ``--config debug=true`` show the traceback too.
* :class:`RawFormatError` - a raw log that cannot be read as documented in
  ``docs/raw-format.md`` (or as its machine's ``input:`` mapping says). It is the
  only error a reader (``rafi.readers.native.read_raw_log``, ``rafi.readers.logs.read_log``) or the
  plausibility checks (``rafi.readers.checks.check_log``) raise for bad *data*.
* :class:`InputSpecError` - the ``input:`` mapping in ``config.yaml`` itself is
  wrong (unknown format, bad unit, ...). It is raised before any file is read and
  is a configuration mistake, not a bad file, so the workflow should stop rather
  than quarantine the file.

Every message of a user error is bounded here, centrally, so that no caller can forget: a
run of text longer than :data:`QUOTE_MAX_CHARS` characters (a quoted field, a header, a
path) is cut to that many with ``...`` and its total length, and the whole message to
:data:`MESSAGE_MAX_CHARS` characters (the location at its start and the end of the
explanation are kept). A 50 MB field thus gives a message of a few hundred characters, not
one of 50 MB in the log, the terminal and the report.

Standard library only (imported while Snakemake plans).
"""

from __future__ import annotations

import re
from pathlib import Path

#: At most this many characters of any offending text (a field, a header, a line) are quoted.
QUOTE_MAX_CHARS = 80

#: A user error's whole message is at most this many characters (plus the cut marker).
MESSAGE_MAX_CHARS = 500

#: A path in a message: kept whole up to this length, else ``.../<file name>``.
PATH_MAX_CHARS = 160

#: Exit statuses (``sysexits.h``) of ``rafi`` for a user error.
EX_USAGE = 64
EX_DATAERR = 65


def shorten(text, limit: int = QUOTE_MAX_CHARS) -> str:
    """``text`` if it is at most ``limit`` characters, else its first ``limit`` characters,
    ``...`` and the total length (``xxxx... (52428800 characters)``), without quotes.

    Parameters
    ----------
    text : str
        Any text (a field, a header, a line).
    limit : int
        Characters kept.

    Returns
    -------
    str
        At most ``limit + 30`` characters.
    """
    text = text if isinstance(text, str) else str(text)
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({len(text)} characters)"


def quote(text, limit: int = QUOTE_MAX_CHARS) -> str:
    """``repr`` of at most ``limit`` characters of ``text``: ``'abc'`` or ``'abc...' (N characters)``.

    Use it instead of ``{value!r}`` for text read from a file: the repr of a huge value is
    never built, and escapes (``\\x00``) count towards the limit.
    """
    text = text if isinstance(text, str) else str(text)
    shown = repr(text[:limit])
    cut = len(text) > limit
    if len(shown) > limit + 2:
        shown, cut = shown[: limit + 1] + shown[0], True
    return f"{shown}... ({len(text)} characters)" if cut else shown


#: A quoted Python repr longer than the quote limit ('...' or "...", its quotes not touching
#: a letter or another quote), or any other run of about 100 characters without white space.
_QUOTED_RUN = "{" + str(QUOTE_MAX_CHARS + 1) + ",}"
_BARE_RUN = "{" + str(QUOTE_MAX_CHARS + 20) + ",}"  # above what quote() leaves: 'x...'...,
_LONG_RUN = re.compile(
    rf"""(?<![\w'"])'[^'\n]{_QUOTED_RUN}'(?![\w'])|(?<![\w'"])"[^"\n]{_QUOTED_RUN}"(?![\w"])|\S{_BARE_RUN}"""
)


def _shorten_run(match: re.Match) -> str:
    run = match.group(0)
    if len(run) > 1 and run[0] in "'\"" and run[-1] == run[0]:
        return f"{run[: QUOTE_MAX_CHARS + 1]}{run[0]}... ({len(run) - 2} characters)"
    return shorten(run)


def _cut_middle(text: str, limit: int) -> str:
    """``text`` cut to at most ``limit`` characters: two thirds from its start, one third
    from its end, ``[... N characters cut ...]`` between."""
    if len(text) <= limit:
        return text
    marker_room = 40  # " [... 123456789 characters cut ...] "
    keep = max(limit - marker_room, 2)
    head, tail = text[: keep - keep // 3], text[len(text) - keep // 3 :]
    return f"{head} [... {len(text) - len(head) - len(tail)} characters cut ...] {tail}"[:limit]


def bound_message(message, limit: int = MESSAGE_MAX_CHARS) -> str:
    """A one-line message with every long run of text shortened (to :data:`QUOTE_MAX_CHARS`
    characters, with ``...`` and its length) and at most ``limit`` characters in all: the
    start (the location) and the end (what to do) are kept, the middle is cut.

    Parameters
    ----------
    message : str
        Any message (it may quote text read from a file).
    limit : int
        Characters at most.

    Returns
    -------
    str
        The bounded message (unchanged when it was short, on one line and had no long run).
        Linear in the message's length (about 1 s for 50 MB).
    """
    message = message if isinstance(message, str) else str(message)
    message = _LONG_RUN.sub(_shorten_run, message)
    if "\n" in message or "\r" in message:
        message = " ".join(message.split())
    return _cut_middle(message, limit)


def short_path(path) -> str:
    """A path for a message: whole if at most :data:`PATH_MAX_CHARS` characters, else
    ``.../<name>`` (the name shortened to :data:`QUOTE_MAX_CHARS` characters if need be)."""
    text = str(path)
    if len(text) <= PATH_MAX_CHARS:
        return text
    return ".../" + shorten(Path(text).name)


class RafiUserError(Exception):
    """Base of the errors a user causes and cures: bad data or a bad configuration.

    The message is bounded (:func:`bound_message`). ``exit_status`` is what ``rafi`` exits
    with for it (:data:`EX_USAGE` for configuration, :data:`EX_DATAERR` for data).
    """

    exit_status = EX_USAGE

    def __init__(self, message: str = "", *args):
        super().__init__(bound_message(message), *args)


class RawFormatError(RafiUserError, ValueError):
    """A log file that cannot be read as documented in ``docs/raw-format.md``.

    The message always names the file and, where known, the line (1-based, as an
    editor shows it) - or, for a spreadsheet, the sheet and row (1-based, as Excel
    shows it) - and the column, then what was found and what was expected.

    Parameters
    ----------
    path : str or Path
        File that failed.
    message : str
        What was found and what was expected.
    line : int, optional
        1-based line number in the file (row number for a spreadsheet).
    column : str, optional
        Column name (as written in the file's header) concerned.
    sheet : str, optional
        Worksheet name for spreadsheets; the location then reads ``sheet 'S', row N``.
    check : str, optional
        The check id (``docs/raw-format.md``: ``line_too_long``, ``unreadable``, ...) when the
        error is one of the documented checks.

    The message is bounded (:func:`bound_message`): a path, sheet or column longer than
    the quote limit is shortened, and so is any long text the caller quoted, so the message
    always names the file (``.../<name>`` for a very long path) and the line.
    """

    exit_status = EX_DATAERR

    def __init__(
        self,
        path,
        message: str,
        *,
        line: int | None = None,
        column: str | None = None,
        sheet: str | None = None,
        check: str | None = None,
    ):
        self.path = str(path)
        self.line = line
        self.column = column
        self.sheet = sheet
        self.check = check
        where = short_path(self.path)
        if sheet is not None:
            where += f", sheet {quote(sheet, 31)}"
        if line is not None:
            where += f", {'row' if sheet is not None else 'line'} {line}"
        if column is not None:
            where += f", column {quote(column, 60)}"
        # the location is kept whole (at most ~350 characters); the reason gets the rest
        self.reason = bound_message(message, max(MESSAGE_MAX_CHARS - len(where) - 2, 140))
        Exception.__init__(self, f"{where}: {self.reason}")

    @property
    def file_name(self) -> str:
        return Path(self.path).name


class InputSpecError(RafiUserError, ValueError):
    """The per-machine ``input:`` mapping is invalid (a configuration error).

    The message names the offending key (e.g. ``input.displacement.unit``) and the
    accepted values.
    """


class RegistryError(RuntimeError):
    """The registry is inconsistent (hash mismatch, overwrite attempt, unknown model id)."""


class IncompatibleModels(ValueError):
    """Two models cannot be merged speed by speed (different sensors, terms or reference)."""


class LockHeld(RuntimeError):
    """Another process holds the nightly lock; ``holder`` is what it wrote in the file."""

    def __init__(self, path: Path, holder: str):
        self.path = path
        self.holder = holder.strip() or "unknown process"
        super().__init__(f"another nightly run holds {path}: {self.holder}")


class SettingsError(RafiUserError, ValueError):
    """``config.yaml`` puts a setting where nothing reads it, or names an unknown one.

    The message names the key and where it belongs.
    """


class TargetError(RafiUserError, ValueError):
    """A controller target (``rafi.deploy.targets``) refuses a value or its own configuration.

    Raised *before* anything of the sample is written: a value outside the range the
    controller documents or the machine agreed (``SD 43910`` beyond the ``MD 32760`` factor,
    ``SD 43900`` beyond the configured limit, a non-finite number), a missing or unknown axis,
    a write to a closed target, or a target set up wrongly (``SD 43920`` at the axis zero).

    Parameters
    ----------
    message : str
        What was refused and what is allowed.
    target : str, optional
        The target's name (``sinumerik``, ``csv``, ``jsonl``).
    axis : str, optional
        The axis concerned.
    value, limit : float, optional
        The refused value and the limit it broke, in the unit the message names.
    """

    exit_status = EX_DATAERR

    def __init__(self, message: str, *, target=None, axis=None, value=None, limit=None):
        self.target = target
        self.axis = axis
        self.value = value
        self.limit = limit
        where = " ".join(p for p in (target and f"target {target}", axis and f"axis {axis}") if p)
        super().__init__(f"{where}: {message}" if where else message)


class UntrustedCertificate(RafiUserError):
    """The OPC UA server's certificate is refused (``rafi deploy`` with a security policy): not
    valid now, not the pinned one, not the configured fingerprint, or not trusted by the trust
    folder. A trust setting to correct, hence ``EX_USAGE`` (64); the message names the
    certificate (subject, SHA-256 fingerprint), why, and what to do. Nothing is sent to the server."""


class UnqualifiedModel(RafiUserError):
    """A model that may not compensate a machine: it is not the registry's champion (the only
    qualified model, ``rafi.deploy.qualified``), the registry has no champion, or the artefact
    does not verify. Nothing is written to the controller."""

    exit_status = EX_DATAERR


class ReplayError(RafiUserError):
    """``rafi replay`` cannot replay what was asked: the pipeline's results are missing, a run id
    is unknown, no run has a role of ``deploy.replay_roles``, or the model file is not a model
    artefact. The message says what to run or which values exist."""


class PriorUnavailable(RafiUserError):
    """``models.prior`` asks for a prior that does not exist: ``champion`` on a machine whose
    registry has no champion, or ``{machine: <name>}`` naming a machine without a registry or
    champion. A setting to correct (or a qualification to run first), hence ``EX_USAGE`` (64);
    the message names the setting, the registry path and what to do."""


class PriorForeign(RafiUserError):
    """The prior (``models.prior``, ``rafi.family.prior``) is a model of another machine that is
    not declared a sibling of this one (``models.prior_siblings``): a setting to set (or a prior
    to drop), hence ``EX_USAGE`` (64). The one-line message names the prior's model id, its
    machine and the key to set."""


class PriorIncompatible(RafiUserError):
    """The prior (``models.prior``, ``rafi.family.prior``) cannot be applied to this machine's
    data: a temperature sensor it reads is missing, the probe sign or the reference rule
    differs. Bad data for this prior, hence ``EX_DATAERR`` (65); the message names the prior's
    id, what differs and the likely cause (a replaced or renamed sensor, a changed probe
    mounting, a different reference rule)."""

    exit_status = EX_DATAERR
