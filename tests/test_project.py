"""The README's promises about the project itself."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def readme_commands():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    return re.findall(r"```bash\n(.+?)\n```", text)


def test_readme_has_exactly_two_commands():
    commands = readme_commands()
    assert len(commands) == 2, commands
    assert commands[0].endswith("snakemake --cores 2")
    assert "pytest" in commands[1]


def test_ci_runs_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert readme_commands()[1] in ci.splitlines()


def test_build_outputs_are_ignored():
    ignored = (ROOT / ".gitignore").read_text(encoding="utf-8").split()
    assert "/results/" in ignored and "/reports/" in ignored


# --------------------------------------------------------------------------- the package's shape

PACKAGE = ROOT / "rafi"


def _modules() -> dict[str, Path]:
    from rafi.ops.code_deps import module_file

    names = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).with_suffix("")
        parts = ["rafi", *rel.parts]
        if parts[-1] == "__init__":
            parts = parts[:-1]
        name = ".".join(parts)
        assert module_file(name, PACKAGE) == path
        names[name] = path
    return names


def test_no_module_over_600_lines():
    long = {
        str(p.relative_to(ROOT)): n
        for p in PACKAGE.rglob("*.py")
        if (n := len(p.read_text().splitlines())) > 600
    }
    assert not long, long


def test_no_import_cycle():
    """Tarjan's strongly connected components over every rafi import (lazy ones included)."""
    from rafi.ops.code_deps import imported_modules

    modules = _modules()
    graph = {
        name: sorted(m for m in imported_modules(path, PACKAGE) if m in modules and m != name and m != "rafi")
        for name, path in modules.items()
    }
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in graph[node]:
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    assert not cycles, cycles


def test_every_error_type_lives_in_rafi_errors():
    import ast

    defined = {}
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef):
                bases = {getattr(b, "id", getattr(b, "attr", "")) for b in node.bases}
                if any(b.endswith(("Error", "Exception")) for b in bases) or node.name.endswith("Error"):
                    defined[node.name] = str(path.relative_to(ROOT))
    elsewhere = {k: v for k, v in defined.items() if v != "rafi/errors.py"}
    assert not elsewhere, elsewhere
    assert {"RawFormatError", "InputSpecError", "SettingsError", "RegistryError"} <= set(defined)


def test_rafi_code_follows_each_scripts_imports():
    """rafi_code(script) of common.smk: what the script imports, transitively, with the packages'
    __init__ files; nothing it does not import."""
    from rafi.ops.code_deps import code_files

    files = {
        str(Path(p).relative_to(ROOT))
        for p in code_files(ROOT / "workflow" / "scripts" / "method.py", PACKAGE)
    }
    assert {
        "rafi/__init__.py",
        "rafi/method/__init__.py",
        "rafi/method/fit.py",
        "rafi/method/model.py",
        "rafi/method/fuzzy.py",
        "rafi/artefact.py",
    } <= files
    assert not any(f.startswith(("rafi/report/", "rafi/twin/", "rafi/family/")) for f in files), files
    audit = {
        str(Path(p).relative_to(ROOT))
        for p in code_files(ROOT / "workflow" / "scripts" / "input_status.py", PACKAGE)
    }
    assert "rafi/method/audit.py" in audit
