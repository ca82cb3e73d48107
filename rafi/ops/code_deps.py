"""Which ``rafi`` source files a workflow script runs (standard library only).

Snakemake's ``code`` rerun trigger covers a rule's script file, not the modules the script
imports. The workflow lists those modules as ``input:`` of each rule; this module derives the
list from the script's own imports, followed transitively through the package, so it cannot
drift from the code: editing ``rafi/method/rank.py`` re-runs ``rank`` and what follows it,
and nothing upstream.
"""

from __future__ import annotations

import ast
import functools
import hashlib
from pathlib import Path

#: Statement-like nodes whose lists may hold statements (function and class bodies, if /
#: try / with / match blocks): the only places an import can be.
_STATEMENTS = (ast.stmt, ast.excepthandler, ast.match_case)


def module_file(name: str, package_dir: Path) -> Path | None:
    """Source file of the dotted module ``name`` (``rafi.x.y``) under ``package_dir``, if any."""
    parts = name.split(".")[1:]
    base = package_dir.joinpath(*parts)
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if parts and candidate.is_file():
            return candidate
    if not parts:
        return package_dir / "__init__.py"
    return None


def _package_of(path: Path, package_dir: Path) -> str:
    """The package a source file belongs to (``rafi/a/b.py`` and ``rafi/a/__init__.py``: ``rafi.a``)."""
    return ".".join(["rafi", *path.relative_to(package_dir).parent.parts])


@functools.cache
def imported_modules(path: Path, package_dir: Path) -> frozenset[str]:
    """Dotted names of the ``rafi`` modules ``path`` imports, at any depth (also inside functions).

    ``from rafi.x import y`` counts ``rafi.x`` and, where ``y`` is a module, ``rafi.x.y``;
    relative imports are resolved against the file's package.
    """
    tree = ast.parse(Path(path).read_text(encoding="utf-8"))
    inside = path.is_relative_to(package_dir)
    names: set[str] = set()
    stack = list(tree.body)
    while stack:
        node = stack.pop()
        if isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:
                if not inside:
                    continue
                base = _package_of(path, package_dir).split(".")
                base = base[: len(base) - (node.level - 1)]
                module = ".".join([*base, module] if module else base)
            if module == "rafi" or module.startswith("rafi."):
                names.add(module)
                for alias in node.names:
                    sub = f"{module}.{alias.name}"
                    if module_file(sub, package_dir) is not None:
                        names.add(sub)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names if a.name == "rafi" or a.name.startswith("rafi."))
        else:
            for _, value in ast.iter_fields(node):
                if isinstance(value, list):
                    stack.extend(v for v in value if isinstance(v, _STATEMENTS))
    return frozenset(names)


def _with_parents(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[: i + 1]) for i in range(len(parts))]


def code_files(script: str | Path, package_dir: str | Path) -> list[str]:
    """Sorted paths of every ``rafi`` source file that running ``script`` imports.

    Parameters
    ----------
    script : str or Path
        A workflow script (or any Python file).
    package_dir : str or Path
        The ``rafi`` package folder (where its ``__init__.py`` is).

    Returns
    -------
    list of str
        The modules the script imports, what they import in turn, and the ``__init__.py``
        of every package on the way (importing ``rafi.a.b`` runs ``rafi/__init__.py`` and
        ``rafi/a/__init__.py``).
    """
    package_dir = Path(package_dir).resolve()
    todo = list(imported_modules(Path(script).resolve(), package_dir))
    seen: set[str] = set()
    while todo:
        name = todo.pop()
        for dotted in _with_parents(name):
            if dotted in seen:
                continue
            path = module_file(dotted, package_dir)
            if path is None:
                continue
            seen.add(dotted)
            todo.extend(imported_modules(path, package_dir) - seen)
    return sorted(str(module_file(n, package_dir)) for n in seen)


def code_version(script: str | Path, package_dir: str | Path | None = None) -> str:
    """Digest of what running ``script`` executes: the script, the ``_glue.py`` beside it, every
    ``rafi`` module it imports (:func:`code_files`) and, when it runs the report package, its
    templates. A rule carries it as the param ``code``, so Snakemake's own ``params`` trigger
    re-runs the rule when any of that code changed (and only then).

    Returns
    -------
    str
        ``sha256:<hex>`` over the files' paths (relative) and bytes.
    """
    script = Path(script).resolve()
    package_dir = Path(package_dir).resolve() if package_dir else Path(__file__).resolve().parents[1]
    files = [Path(p) for p in code_files(script, package_dir)]
    if any(p.is_relative_to(package_dir / "report") for p in files):
        files += sorted((package_dir / "report" / "templates").rglob("*.j2"))
    digest = hashlib.sha256()
    for path, label in [(script, script.name), (script.parent / "_glue.py", "_glue.py")]:
        if path.is_file():
            digest.update(f"{label}\n".encode() + path.read_bytes())
    for path in files:
        digest.update(f"{path.relative_to(package_dir.parent)}\n".encode() + path.read_bytes())
    return f"sha256:{digest.hexdigest()}"
