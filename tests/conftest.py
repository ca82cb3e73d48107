"""What every test module shares: how a test that needs a system program behaves without it, and
in which order the tests run.

On a fresh machine (the README's test command, nothing installed beyond Python) a test that needs
Chromium, poppler-utils, Slurm or a private mount namespace is skipped with a one-line reason. Under
``CI=true`` (``.ci/run``, which installs and starts them) the same test fails instead: CI runs every
test, and a missing program there is a broken CI, not a reason to skip.

The tests run on every core (pytest-xdist, ``--dist loadgroup`` in pyproject.toml): the tests of a
module that share a module- or session-scoped fixture of that module (a pipeline run, a rendered
report) go to one worker, so it is made once, and the slow tests (marker ``slow``) start first, so
that no long test starts last and keeps one core busy while the others wait
(:func:`pytest_collection_modifyitems`).
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


def shared_fixture_module(item: pytest.Item) -> str | None:
    """The module of ``item`` if ``item`` uses a fixture of wider than function scope defined in
    its own module (which every worker running one of that module's tests would make again),
    else None."""
    module = item.nodeid.split("::", 1)[0]
    info = getattr(item, "_fixtureinfo", None)
    for defs in info.name2fixturedefs.values() if info else ():
        if defs and defs[-1].scope != "function" and defs[-1].baseid == module:
            return module
    return None


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the xdist_group markers
def pytest_collection_modifyitems(config, items):
    """Group each module's tests that share a module-scoped fixture (marker ``xdist_group``, one
    worker makes it once) and start the slow tests first: a test, or a group holding a slow test,
    marked ``slow`` goes before every other, in collection order otherwise."""
    unit = {}
    for item in items:
        module = shared_fixture_module(item)
        if module is not None:
            item.add_marker(pytest.mark.xdist_group(module))
        unit[item.nodeid] = module or item.nodeid
    slow = {unit[item.nodeid] for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: unit[item.nodeid] not in slow)
