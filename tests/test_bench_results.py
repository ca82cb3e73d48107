"""benchmarks/_results.py: the one writer of benchmarks/results (both files, atomically, each
benchmark's JSON format kept), and a scan that no benchmark writes there by itself."""

from __future__ import annotations

import ast
import json
import os
from pathlib import Path

import numpy as np
import pytest
from bench_loader import load_bench

ROOT = Path(__file__).resolve().parents[1]
BENCH_DIR = ROOT / "benchmarks"
results = load_bench("_results")


def test_write_results_writes_the_json_and_the_markdown_and_returns_their_paths(tmp_path):
    report = {"b": [1, 2.5], "a": {"machine": "m", "ok": True}, "path": Path("x/y.csv"), "none": None}
    out_dir = tmp_path / "new" / "results"  # created on the way
    paths = results.write_results("bench", report, "| a |\n", out_dir=out_dir)
    assert paths == (out_dir / "bench.json", out_dir / "bench.md")
    assert json.loads(paths[0].read_text(encoding="utf-8")) == {**report, "path": "x/y.csv"}
    assert list(json.loads(paths[0].read_text(encoding="utf-8"))) == ["b", "a", "path", "none"]
    assert paths[1].read_text(encoding="utf-8") == "| a |\n"
    assert sorted(p.name for p in out_dir.iterdir()) == ["bench.json", "bench.md"]


def test_without_text_only_the_json_is_written(tmp_path):
    assert results.write_results("only", {"a": 1}, out_dir=tmp_path) == (tmp_path / "only.json",)
    assert [p.name for p in tmp_path.iterdir()] == ["only.json"]


def test_the_default_folder_is_benchmarks_results():
    assert results.OUT_DIR == BENCH_DIR / "results"


REPORT = {"z": np.int64(3), "um": "\u00b5m", "x": [0.5]}


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        # bench_selection_rules, bench_foreign, bench_plain_ridge: the defaults
        ({}, '{\n  "z": "3",\n  "um": "\\u00b5m",\n  "x": [\n    0.5\n  ]\n}'),
        # bench_realdata, bench_learning_curve
        ({"ensure_ascii": False}, '{\n  "z": "3",\n  "um": "\u00b5m",\n  "x": [\n    0.5\n  ]\n}'),
        # bench_pipeline, bench_fleet
        ({"final_newline": True}, '{\n  "z": "3",\n  "um": "\\u00b5m",\n  "x": [\n    0.5\n  ]\n}\n'),
        # bench_requalify
        (
            {"indent": 1, "default": float, "final_newline": True},
            '{\n "z": 3.0,\n "um": "\\u00b5m",\n "x": [\n  0.5\n ]\n}\n',
        ),
    ],
)
def test_each_benchmarks_json_format_is_kept_byte_for_byte(tmp_path, options, expected):
    (path,) = results.write_results("fmt", REPORT, out_dir=tmp_path, **options)
    assert path.read_bytes() == expected.encode("utf-8")


def _previous_files(tmp_path: Path) -> tuple[Path, Path]:
    results.write_results("bench", {"run": "old"}, "old table\n", out_dir=tmp_path)
    return tmp_path / "bench.json", tmp_path / "bench.md"


def test_a_failing_rename_leaves_the_previous_files_and_no_temporary_file(tmp_path, monkeypatch):
    old_json, old_md = (p.read_bytes() for p in _previous_files(tmp_path))

    def refuse(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", refuse)
    with pytest.raises(OSError, match="No space left"):
        results.write_results("bench", {"run": "new"}, "new table\n", out_dir=tmp_path)
    assert (tmp_path / "bench.json").read_bytes() == old_json
    assert (tmp_path / "bench.md").read_bytes() == old_md
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bench.json", "bench.md"]


def test_a_failure_on_the_markdown_keeps_its_previous_file_beside_the_new_json(tmp_path, monkeypatch):
    json_path, md_path = _previous_files(tmp_path)
    real_replace = os.replace

    def refuse_markdown(src, dst):
        if str(dst).endswith(".md"):
            raise OSError(5, "Input/output error")
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", refuse_markdown)
    with pytest.raises(OSError, match="Input/output"):
        results.write_results("bench", {"run": "new"}, "new table\n", out_dir=tmp_path)
    assert json.loads(json_path.read_text()) == {"run": "new"}
    assert md_path.read_text() == "old table\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bench.json", "bench.md"]


def test_a_report_json_cannot_encode_writes_nothing(tmp_path):
    json_path, _ = _previous_files(tmp_path)
    with pytest.raises(TypeError):  # bench_requalify's default=float on a value float() refuses
        results.write_results("bench", {"run": object()}, out_dir=tmp_path, default=float)
    assert json.loads(json_path.read_text()) == {"run": "old"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bench.json", "bench.md"]


# ----------------------------------------------------------------------------- the scan

#: Method calls that write to their receiver, and calls that write to their n-th argument.
WRITE_METHODS = {"write_text", "write_bytes", "to_csv", "to_parquet", "to_json", "to_excel", "savefig"}
FRAME_WRITERS = {"to_csv", "to_parquet", "to_json", "to_excel", "savefig"}  # path: argument 0
WRITE_FUNCTIONS = {
    "write_text_atomic": 0,
    "write_bytes_atomic": 0,
    "atomic_path": 0,
    "write_csv_atomic": 1,
    "write_parquet_atomic": 1,
    "copy": 1,
    "copy2": 1,
    "copyfile": 1,
    "move": 1,
}


def _writes_to(call: ast.Call) -> list[ast.expr]:
    """The expressions naming the file(s) ``call`` writes (empty when it writes none)."""
    func = call.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
    targets: list[ast.expr] = []
    if isinstance(func, ast.Attribute) and name in WRITE_METHODS:
        targets.append(func.value)
        if name in FRAME_WRITERS and call.args:
            targets.append(call.args[0])
    if name in WRITE_FUNCTIONS and len(call.args) > WRITE_FUNCTIONS[name]:
        targets.append(call.args[WRITE_FUNCTIONS[name]])
    if name == "open":
        is_method = isinstance(func, ast.Attribute)
        mode_args = call.args[0 if is_method else 1 :]
        mode = next((k.value for k in call.keywords if k.arg == "mode"), None)
        mode = mode if mode is not None else (mode_args[0] if mode_args else ast.Constant("r"))
        writing = not isinstance(mode, ast.Constant) or any(c in str(mode.value) for c in "wax+")
        if writing:
            targets.append(func.value if is_method else call.args[0])
    return targets


def _argparse_dests(tree: ast.AST, is_results) -> set[str]:
    """Options (``args.<dest>``) whose default points into benchmarks/results."""
    dests = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "add_argument":
            default = next((k.value for k in node.keywords if k.arg == "default"), None)
            flag = next((a.value for a in node.args if isinstance(a, ast.Constant)), "")
            dest = next((k.value.value for k in node.keywords if k.arg == "dest"), flag.lstrip("-"))
            if default is not None and is_results(default):
                dests.add(dest.replace("-", "_"))
    return dests


def results_writes(source: str) -> list[str]:
    """Each write of ``source`` into benchmarks/results, as ``line: code``.

    A path is into benchmarks/results when its expression holds ``OUT_DIR``, the strings
    ``"benchmarks"`` and ``"results"`` (or ``"benchmarks/results"``), an option whose default is
    such a path (``args.out``), or a variable assigned from any of these in the same function or
    at module level.
    """
    tree = ast.parse(source)
    names: set[str] = {"OUT_DIR"}
    dests: set[str] = set()

    def is_results(expr: ast.AST) -> bool:
        nodes = list(ast.walk(expr))
        strings = {n.value for n in nodes if isinstance(n, ast.Constant) and isinstance(n.value, str)}
        if {"benchmarks", "results"} <= strings or any("benchmarks/results" in s for s in strings):
            return True
        return any(
            (isinstance(n, ast.Name) and n.id in names)
            or (isinstance(n, ast.Attribute) and n.attr == "OUT_DIR")
            or (isinstance(n, ast.Attribute) and n.attr in dests and isinstance(n.value, ast.Name))
            for n in nodes
        )

    def tainted(assigns: list[ast.AST]) -> set[str]:
        found = set(names)
        for _ in range(len(assigns) + 1):  # to a fixed point: a name assigned from one tainted later
            for node in assigns:
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                if node.value is not None and is_results(node.value):
                    found |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
            names.update(found)
        return found

    dests = _argparse_dests(tree, is_results)
    functions = [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)]
    in_function = {id(n) for fn in functions for n in ast.walk(fn) if n is not fn}
    top = [n for n in ast.walk(tree) if id(n) not in in_function]
    scopes = [top, *([n for n in ast.walk(fn) if n is not fn] for fn in functions)]
    module_names = set(names)
    writes = set()
    for i, nodes in enumerate(scopes):
        names = set(module_names)  # each function sees the module's names and its own
        scope_names = tainted([n for n in nodes if isinstance(n, ast.Assign | ast.AnnAssign | ast.NamedExpr)])
        if i == 0:
            module_names = scope_names
        for call in (n for n in nodes if isinstance(n, ast.Call)):
            if any(is_results(target) for target in _writes_to(call)):
                writes.add(f"{call.lineno}: {ast.get_source_segment(source, call)}")
    return sorted(writes, key=lambda w: int(w.split(":")[0]))


def _benches() -> dict[str, str]:
    return {
        p.name: p.read_text(encoding="utf-8")
        for p in sorted(BENCH_DIR.glob("*.py"))
        if p.name != "_results.py"
    }


#: How the benchmarks wrote their results before _results.py (verbatim from the old sources).
OLD_REALDATA = """
ROOT = Path(__file__).resolve().parents[1]
OUT_DIR = ROOT / "benchmarks" / "results"

def main(argv=None):
    report, text = {}, ""
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    (OUT_DIR / "realdata.json").write_text(json.dumps(report, indent=2, ensure_ascii=False, default=str))
    (OUT_DIR / "realdata.md").write_text(text, encoding="utf-8")
    return 0
"""
OLD_LEARNING_CURVE = """
OUT_DIR = rd.OUT_DIR

def main(argv=None):
    (OUT_DIR / "learning_curve.json").write_text(
        json.dumps(report, indent=2, ensure_ascii=False, default=str)
    )
"""
OLD_FLEET = """
def main_side(args, argv):
    out = args.out.with_name(args.out.name + "-issue23")
    out.with_suffix(".json").write_text(json.dumps(report, indent=2) + "\\n")

def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "fleet")
    args = ap.parse_args(argv)
    (proj / "bench-cold.log").write_text(cold["stderr"])
    args.out.with_suffix(".md").write_text(text)
"""
OLD_REQUALIFY = """
def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "requalify.json"))
    args = p.parse_args(argv)
    out = Path(args.json)
    out.write_text(json.dumps(record, indent=1, default=float) + "\\n", encoding="utf-8")
"""
OLD_SELECTION_RULES = """
OUT_DIR = ROOT / "benchmarks" / "results"

def write_results(stem, report, text):
    write_text_atomic(OUT_DIR / f"{stem}.json", json.dumps(report, indent=2, default=str))
    with open(OUT_DIR / f"{stem}.log", "a") as fh:
        fh.write(text)
"""


@pytest.mark.parametrize(
    ("source", "lines"),
    [
        (OLD_REALDATA, [8, 9]),
        (OLD_LEARNING_CURVE, [5]),
        (OLD_FLEET, [4, 11]),  # not line 10: a temporary project's log
        (OLD_REQUALIFY, [7]),
        (OLD_SELECTION_RULES, [5, 6]),
    ],
)
def test_the_scan_finds_the_old_ways_of_writing_results(source, lines):
    assert [int(w.split(":")[0]) for w in results_writes(source)] == lines


def test_the_scan_tells_results_apart_from_other_files_and_reads():
    kept = """
def main(argv=None):
    p.add_argument("--out", default=ROOT / "benchmarks" / "results" / "x")
    p.add_argument("--keep", type=Path)
    args = p.parse_args(argv)
    (args.keep / "config.yaml").write_text("")
    with open(args.keep / "log", "w") as fh:
        fh.write("")
    with open(args.out.with_suffix(".json")) as fh:  # read
        json.load(fh)
    write_results(args.out.stem, {}, "", out_dir=args.out.parent)
    args.out.with_suffix(".csv").open("w")
"""
    assert results_writes(kept) == ['12: args.out.with_suffix(".csv").open("w")']


def test_no_benchmark_writes_into_benchmarks_results_by_itself():
    benches = _benches()
    assert {"bench_realdata.py", "bench_fleet.py", "bench_requalify.py"} <= set(benches)
    found = {name: writes for name, src in benches.items() if (writes := results_writes(src))}
    assert found == {}, "write through benchmarks/_results.py write_results instead"


def test_the_scan_reads_the_benchmarks_own_writes_of_other_files():
    # the scan is not blind on the real sources: it sees bench_fleet's writes into its projects
    tree = ast.parse(_benches()["bench_fleet.py"])
    writes = [c for c in ast.walk(tree) if isinstance(c, ast.Call) and _writes_to(c)]
    assert len(writes) >= 3


def test_every_benchmark_that_names_benchmarks_results_writes_through_write_results():
    for name, src in _benches().items():
        tree = ast.parse(src)
        if "benchmarks/results" not in (ast.get_docstring(tree) or ""):
            continue
        calls = {getattr(c.func, "id", "") for c in ast.walk(tree) if isinstance(c, ast.Call)}
        assert "write_results" in calls, name
