"""Every file of the bad-input corpus is refused with a RawFormatError that says where and why.

The corpus and the expected outcome of each file live in ``tests/data/bad/make_bad.py``
(``CASES``; also listed in ``tests/data/bad/README.md``).
"""

from __future__ import annotations

import hashlib
import importlib.util
import sys
from pathlib import Path

import pytest

from rafi.errors import RawFormatError
from rafi.readers.checks import check_log
from rafi.readers.logs import read_log

BAD = Path(__file__).resolve().parent / "data" / "bad"


def _load_corpus():
    spec = importlib.util.spec_from_file_location("rafi_bad_corpus", BAD / "make_bad.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses need the module registered
    spec.loader.exec_module(module)
    return module


corpus = _load_corpus()


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_corpus_is_complete():
    files = {p.name for p in BAD.iterdir() if p.suffix in (".csv", ".xlsx")}
    listed = {c.file for c in corpus.CASES}
    assert files == listed
    assert len(listed) >= 15
    readme = (BAD / "README.md").read_text(encoding="utf-8")
    for name in listed:
        assert f"`{name}`" in readme


@pytest.mark.parametrize("case", corpus.CASES, ids=[c.file for c in corpus.CASES])
def test_bad_file_is_refused_with_location(case):
    path = BAD / case.file
    before = _sha(path)
    with pytest.raises(RawFormatError) as info:
        frame = read_log(path, corpus.SPECS[case.spec])
        check_log(frame, path, **{**corpus.CHECKS, **case.checks})
    err = info.value
    message = str(err)
    assert case.file in message
    assert err.file_name == case.file
    assert case.fragment in message
    assert err.line == case.line
    assert err.column == case.column
    if case.line is not None:
        word = "row" if case.sheet else "line"
        assert f"{word} {case.line}" in message
    if case.column is not None:
        assert repr(case.column) in message
    if case.sheet is not None:
        assert err.sheet == case.sheet and f"sheet {case.sheet!r}" in message
    assert _sha(path) == before, "a raw file was modified by reading or checking it"


def test_raw_files_are_opened_read_only(monkeypatch):
    """No reader or check opens a raw file for writing (belt and braces to the hash test)."""
    import builtins
    import io as _io

    real_open = builtins.open
    modes = []

    def spy(file, mode="r", *args, **kwargs):
        if str(file).startswith(str(BAD)):
            modes.append(mode)
        return real_open(file, mode, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", spy)
    monkeypatch.setattr(_io, "open", spy)
    for case in corpus.CASES:
        path = BAD / case.file
        try:
            check_log(read_log(path, corpus.SPECS[case.spec]), path, **{**corpus.CHECKS, **case.checks})
        except RawFormatError:
            pass
    assert all(set(m) <= set("rbt") for m in modes), modes
