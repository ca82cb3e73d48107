"""Fonts for the report's text beyond Latin: the Chinese, Japanese or Korean headers of a log.

The report's fonts (DejaVu Sans) have no CJK glyphs; WeasyPrint would draw such characters as
empty boxes (``.notdef``). Every font stack of the report's CSS therefore ends in the CJK
families of :data:`CJK_FAMILIES` (:func:`css_families`), and the figures' ``font.family`` lists
the installed ones after DejaVu Sans (:func:`matplotlib_families`: matplotlib falls back glyph by
glyph along the list). Where none is installed the text stays as written and the report says
that its PDF lacks a font for these characters (:func:`missing_font_note`).
"""

from __future__ import annotations

import functools
import re
import shutil
import subprocess

#: CJK families tried after the report's own fonts, in order: what Debian's fonts-noto-cjk,
#: fonts-wqy-zenhei / fonts-wqy-microhei and fonts-droid-fallback install.
CJK_FAMILIES = (
    "Noto Sans CJK SC",
    "Noto Sans CJK JP",
    "WenQuanYi Zen Hei",
    "WenQuanYi Micro Hei",
    "Droid Sans Fallback",
)
#: The Debian package the note names.
CJK_PACKAGE = "fonts-noto-cjk"
#: The figures' own font, first in their font list.
FIGURE_FONT = "DejaVu Sans"

#: Characters no Latin font of the report draws: CJK radicals and symbols, kana, Hangul, the
#: unified ideographs (with extension A), compatibility ideographs, full-width forms.
_CJK = re.compile("[\u2e80-\u4dbf\u4e00-\u9fff\uac00-\ud7af\uf900-\ufaff\ufe30-\ufe4f\uff00-\uffef]+")


def cjk_runs(text: str) -> list[str]:
    """The runs of CJK characters in ``text``, in order (``[]`` for none)."""
    return _CJK.findall(str(text))


def _fc_list(fields: str) -> str | None:
    """``fc-list --format <fields> :lang=zh`` (the fonts fontconfig has for Chinese); None without
    a working fc-list."""
    fc_list = shutil.which("fc-list")
    if fc_list is None:
        return None
    try:
        cmd = [fc_list, "--format", fields, ":lang=zh"]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout if done.returncode == 0 else None


def _fontconfig_families() -> set[str] | None:
    """Families fontconfig has for Chinese (``fc-list :lang=zh``); None without fc-list."""
    out = _fc_list("%{family}\n")
    if out is None:
        return None
    return {name.strip() for line in out.splitlines() for name in line.split(",") if name.strip()}


def _matplotlib_names() -> set[str]:
    from matplotlib import font_manager

    return {f.name for f in font_manager.fontManager.ttflist}


@functools.cache
def installed_cjk_families() -> tuple[str, ...]:
    """The families of :data:`CJK_FAMILIES` installed on this computer, in that order.

    Returns
    -------
    tuple of str
        Looked up with fontconfig (what WeasyPrint draws with); with matplotlib's font list
        where ``fc-list`` is missing. Empty: no CJK font.
    """
    found = _fontconfig_families()
    if found is None:
        found = _matplotlib_names()
    return tuple(name for name in CJK_FAMILIES if name in found)


def css_families() -> str:
    """The CJK families as a CSS font-family fragment (``"Noto Sans CJK SC", ...``), every one
    of :data:`CJK_FAMILIES`, installed or not (a family that is not installed is skipped)."""
    return ", ".join(f'"{name}"' for name in CJK_FAMILIES)


def _register_with_matplotlib(names: tuple[str, ...]) -> None:
    """Add the font files of ``names`` that fontconfig has but matplotlib's font cache (built
    before the fonts were installed) lacks."""
    missing = set(names) - _matplotlib_names()
    out = _fc_list("%{family}\t%{file}\n") if missing else None
    if out is None:
        return
    from matplotlib import font_manager

    files = set()
    for line in out.splitlines():
        families, _, path = line.partition("\t")
        if path and missing & {f.strip() for f in families.split(",")}:
            files.add(path)
    for path in sorted(files):
        font_manager.fontManager.addfont(path)


def matplotlib_families() -> list[str]:
    """``font.family`` of the figures: :data:`FIGURE_FONT`, then the installed CJK families
    (each known to matplotlib, added from fontconfig's files where its cache predates them)."""
    names = installed_cjk_families()
    if names:
        _register_with_matplotlib(names)
        known = _matplotlib_names()
        names = tuple(n for n in names if n in known)
    return [FIGURE_FONT, *names]


def missing_font_note(html: str) -> str | None:
    """The report's note when its text has CJK characters and no CJK font is installed, else None.

    Parameters
    ----------
    html : str
        The rendered report.

    Returns
    -------
    str or None
        A sentence naming an example of the characters and the package to install.
    """
    runs = cjk_runs(html)
    if not runs or installed_cjk_families():
        return None
    return (
        f"This report holds Chinese, Japanese or Korean characters (for example \u201c{runs[0][:12]}\u201d, "
        "in a log's headers or the configuration) and this computer has no font for them (none of "
        f"{', '.join(CJK_FAMILIES)}): they are written as they are, but the PDF shows them as empty "
        f"boxes. Install the package {CJK_PACKAGE} (apt-get install {CJK_PACKAGE}) and build the "
        "report again."
    )
