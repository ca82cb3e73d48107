"""The README's promises about the project itself."""

import re
from pathlib import Path

import pytest

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


def test_code_files_follow_each_scripts_imports():
    """code_files(script), behind each rule's param ``code``: what the script imports,
    transitively, with the packages' __init__ files; nothing it does not import."""
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
    assert not any(f.startswith(("rafi/report/", "rafi/twin/")) for f in files), files
    # of the family, only what RAFI's own whole-run CV and its prediction interval need (issue 26:
    # model.json carries an interval calibrated on RAFI's CV residuals); not the other kinds
    assert {"rafi/family/crossval.py", "rafi/family/intervals.py", "rafi/family/published.py"} <= files
    family = {f for f in files if f.startswith("rafi/family/")}
    others = {
        "compare",
        "ridge",
        "ridge_global",
        "dynamic",
        "grey_box",
        "selection",
        "cv_memo",
        "rafi_linear",
    }
    assert not {f"rafi/family/{name}.py" for name in others} & family, family
    audit = {
        str(Path(p).relative_to(ROOT))
        for p in code_files(ROOT / "workflow" / "scripts" / "input_status.py", PACKAGE)
    }
    assert "rafi/method/audit.py" in audit


def test_code_version_changes_with_the_code_a_script_runs_and_only_then(tmp_path):
    """The param ``code`` of a rule (common.smk code_version): the digest of the script, its glue
    and the rafi modules (and, for the report, the templates) it runs."""
    import shutil

    from rafi.ops.code_deps import code_version

    package = tmp_path / "rafi"
    shutil.copytree(PACKAGE, package, ignore=shutil.ignore_patterns("__pycache__"))
    scripts = tmp_path / "scripts"
    shutil.copytree(ROOT / "workflow" / "scripts", scripts)
    method, report = scripts / "method.py", scripts / "report.py"
    before = {s: code_version(s, package) for s in (method, report)}
    assert before == {s: code_version(s, package) for s in (method, report)}
    rank = package / "method" / "rank.py"
    rank.write_text(rank.read_text(encoding="utf-8") + "\n# an edit\n", encoding="utf-8")
    assert code_version(method, package) != before[method]
    template = package / "report" / "templates" / "sections" / "verdict.html.j2"
    template.write_text(template.read_text(encoding="utf-8") + "\n", encoding="utf-8")
    assert code_version(report, package) != before[report]
    twin = package / "twin" / "simulate.py"
    after_rank = code_version(method, package)
    twin.write_text(twin.read_text(encoding="utf-8") + "\n# not run by rule method\n", encoding="utf-8")
    assert code_version(method, package) == after_rank


# --------------------------------------------------------------------------- layers and sizes

#: What each package may import from rafi besides itself (docs/design.md, "Dependencies").
ALLOWED_IMPORTS = {
    "readers": {"rafi", "rafi.settings", "rafi.contract", "rafi.artefact", "rafi.errors"},
    "method": {"rafi", "rafi.settings", "rafi.contract", "rafi.artefact", "rafi.errors"},
}
#: What a package must never import.
FORBIDDEN_IMPORTS = {"report": ("rafi.ops",), "contract": ("rafi.",)}


def _imports_by_package() -> dict[str, dict[str, set[str]]]:
    from rafi.ops.code_deps import imported_modules

    found: dict[str, dict[str, set[str]]] = {}
    for name, path in _modules().items():
        parts = name.split(".")
        if len(parts) < 2:
            continue
        found.setdefault(parts[1], {})[name] = set(imported_modules(path, PACKAGE))
    return found


def test_readers_and_method_import_only_settings_contract_artefact_and_errors():
    imports = _imports_by_package()
    for package, allowed in ALLOWED_IMPORTS.items():
        own = f"rafi.{package}"
        bad = {
            module: sorted(
                m
                for m in used
                if m != own
                and not m.startswith(own + ".")
                and m not in allowed
                and not m.startswith("rafi.contract.")
            )
            for module, used in imports[package].items()
        }
        assert not {m: b for m, b in bad.items() if b}, bad


def test_the_report_does_not_import_ops_and_the_contract_imports_nothing_of_rafi():
    imports = _imports_by_package()
    for package, forbidden in FORBIDDEN_IMPORTS.items():
        own = f"rafi.{package}"
        bad = {
            module: sorted(m for m in used if m.startswith(forbidden) and not m.startswith(own))
            for module, used in imports[package].items()
        }
        assert not {m: b for m, b in bad.items() if b}, bad


def test_the_contract_is_standard_library_only():
    import ast
    import sys

    for path in (PACKAGE / "contract").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module]
                if isinstance(node, ast.ImportFrom) and node.level == 0
                else []
            )
            for name in names:
                top = name.split(".")[0]
                assert top in sys.stdlib_module_names or top in ("rafi", "__future__"), (path, name)


def test_every_command_help_reads_as_plain_text(capsys):
    """``rafi <command> --help`` shows the module docstring to a user: no reStructuredText roles
    (``:data:`MACHINE_DEFAULTS```) or double backquotes (issue 24: ``rafi settings --help``)."""
    import rafi.cli

    for name in rafi.cli.COMMANDS:
        with pytest.raises(SystemExit):
            rafi.cli.main([name, "--help"])
        text = capsys.readouterr().out
        assert text.startswith(f"usage: rafi {name}"), name
        assert not re.search(r":[a-z]+:`|``", text), (name, re.search(r".*(:[a-z]+:`|``).*", text).group(0))
