"""What every test module shares: how a test that needs a system program behaves without it, in
which order the tests run, and the figures a plotting function draws, kept (:func:`kept_figures`).

On a fresh machine (the README's test command, nothing installed beyond Python) a test that needs
Chromium, poppler-utils, Slurm or a private mount namespace is skipped with a one-line reason. Under
``CI=true`` (``.ci/run``, which installs and starts them) the same test fails instead: CI runs every
test, and a missing program there is a broken CI, not a reason to skip.

The tests run on every core (pytest-xdist, pyproject.toml: a module at a time per worker, in
collection order); the modules with a slow test (marker ``slow``) start first, so that no long test
starts last and keeps one core busy while the other waits (:func:`pytest_collection_modifyitems`).
"""

from __future__ import annotations

import logging
import os
import shutil

import pytest

#: Debian packages of the programs the tests look for (what to install when one is missing).
PACKAGE_OF = {
    "chromium": "chromium",
    "pdftoppm": "poppler-utils",
    "pdftotext": "poppler-utils",
    "pdfimages": "poppler-utils",
    "pdfinfo": "poppler-utils",
    "pdftohtml": "poppler-utils",
    "pdfdetach": "poppler-utils",
    "systemd-analyze": "systemd",
}


def in_ci() -> bool:
    """True when ``CI`` is set to a true value (``.ci/run`` sets ``CI=true``)."""
    return os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")


def require(reason: str | None) -> None:
    """Skip the calling test with ``reason`` (or fail under ``CI=true``); nothing if ``reason`` is None."""
    if reason is None:
        return
    if in_ci():
        pytest.fail(f"{reason} (CI=true: .ci/run installs and starts what the tests need)", pytrace=False)
    pytest.skip(reason)


def which_or_skip(name: str, *alternatives: str) -> str:
    """Path of program ``name`` (or the first of ``alternatives`` found); skip or fail without one."""
    for candidate in (name, *alternatives):
        path = shutil.which(candidate)
        if path:
            return path
    package = PACKAGE_OF.get(name, name)
    require(f"{name} not installed (apt-get install {package}; .ci/run installs it)")
    raise AssertionError("unreachable")  # require() skipped or failed


_ROOT = logging.getLogger()
_ROOT_LEVEL = _ROOT.level


@pytest.fixture(autouse=True)
def _root_logging_as_it_was():
    """Leave the root logger as the test found it: a handler a library added in-process (a
    Snakemake run in a test binds one to the stderr pytest captured, closed after the test)
    would make every later log record from a background thread print a "Logging error"
    into another test's captured stderr. pytest's own handlers are left alone."""
    before = set(_ROOT.handlers)
    yield
    for handler in list(_ROOT.handlers):
        if handler not in before and not type(handler).__module__.startswith("_pytest"):
            _ROOT.removeHandler(handler)
    _ROOT.setLevel(_ROOT_LEVEL)


def pytest_collection_modifyitems(config, items):
    """Start the slow tests first: the modules holding a test marked ``slow`` go before every
    other, in collection order otherwise. pytest-xdist (``--dist loadfile
    --no-loadscope-reorder``) gives a worker the next module when it is almost done with its
    last, so the short modules at the end even out the two workers."""
    slow = {item.nodeid.split("::", 1)[0] for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.nodeid.split("::", 1)[0] not in slow)


@pytest.fixture
def kept_figures(monkeypatch):
    """The matplotlib figures the report's plotting functions draw (``rafi.report.plots.render``),
    kept open instead of rendered, for a test to read back; closed after the test."""
    import matplotlib.pyplot as plt

    from rafi.report import plots

    kept = []
    monkeypatch.setattr(plots, "render", lambda fig, fmt="png": kept.append(fig) or b"")
    yield kept
    for fig in kept:
        plt.close(fig)
