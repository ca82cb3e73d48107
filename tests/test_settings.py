"""The one settings resolver (rafi.settings): layers, the schema, and the two bugs it fixed.

* ``qualification:`` at the top level of config.yaml was valid under the schema, read by the
  decide job and ignored by the compare job (one run, two gate sets): now refused, naming
  where it belongs.
* ``defaults.report.figure_format`` passed the schema and was never read: every key the schema
  allows has one default and is read somewhere.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import jsonschema
import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from rafi import contract
from rafi.errors import SettingsError
from rafi.settings import (
    GATE_KEYS,
    MACHINE_DEFAULTS,
    RUN_DEFAULTS,
    check_layout,
    deep_merge,
    machine_settings,
    one_of_pattern,
    run_settings,
    validate_config,
)

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = yaml.safe_load((ROOT / "workflow" / "schemas" / "config.schema.yaml").read_text(encoding="utf-8"))
CONFIG = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))

#: Sections whose keys are names chosen by the user (not settings): their content is free.
OPEN_MAPS = {("runs", "overrides"), ("input", "columns")}


def _resolve_ref(node: dict) -> dict:
    while "$ref" in node:
        node = SCHEMA["$defs"][node["$ref"].split("/")[-1]]
    return node


def schema_keys(node: dict, prefix: tuple = ()) -> set[tuple]:
    """Every key path the schema allows below ``node`` (leaves and sections)."""
    node = _resolve_ref(node)
    keys = set()
    for key, sub in (node.get("properties") or {}).items():
        path = (*prefix, key)
        keys.add(path)
        if path not in OPEN_MAPS:
            keys |= schema_keys(sub, path)
    return keys


def default_keys(mapping: dict, prefix: tuple = ()) -> set[tuple]:
    keys = set()
    for key, value in mapping.items():
        path = (*prefix, key)
        keys.add(path)
        if isinstance(value, dict) and path not in OPEN_MAPS:
            keys |= default_keys(value, path)
    return keys


def settings_validator() -> jsonschema.Draft202012Validator:
    schema = {"$defs": SCHEMA["$defs"], **SCHEMA["$defs"]["machine_settings"]}
    return jsonschema.Draft202012Validator(schema)


def test_config_validates_and_shipped_machines_resolve_completely():
    jsonschema.validate(CONFIG, SCHEMA)
    validator = settings_validator()
    for machine in ("tapping-center-a", "machining-center-b", "a-machine-without-settings"):
        settings = machine_settings(CONFIG, machine)
        assert set(settings) == set(MACHINE_DEFAULTS)
        settings.pop("input")  # normalised: its defaults are rafi.readers.input_spec's, None included
        validator.validate(settings)


def test_the_schema_file_is_generated_from_the_contract():
    """workflow/schemas/config.schema.yaml is what `python -m rafi.contract` writes, and it holds
    every key of the contract with its type: the contract is the only declaration."""
    text = (ROOT / "workflow" / "schemas" / "config.schema.yaml").read_text(encoding="utf-8")
    assert text == contract.schema_yaml(), "stale: run `python -m rafi.contract`"
    allowed = {k for k in schema_keys(SCHEMA["$defs"]["machine_settings"]) if k[0] != "input"}
    assert allowed == {k for k in default_keys(MACHINE_DEFAULTS) if k[0] != "input"}
    assert set(SCHEMA["properties"]) - {"defaults", "machines"} == set(RUN_DEFAULTS)


def test_docs_settings_tables_are_generated_from_the_contract():
    text = (ROOT / "docs" / "settings.md").read_text(encoding="utf-8")
    assert text == contract.with_settings_tables(text), "stale: run `python -m rafi.contract`"


def test_the_generator_rewrites_a_stale_schema_and_table(tmp_path):
    for rel in ("workflow/schemas/config.schema.yaml", "docs/settings.md"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text((ROOT / rel).read_text(encoding="utf-8"), encoding="utf-8")
    assert contract.write_generated(tmp_path) == []
    schema = tmp_path / "workflow/schemas/config.schema.yaml"
    schema.write_text(schema.read_text(encoding="utf-8").replace('"minimum": 0', '"minimum": 1'))
    assert contract.write_generated(tmp_path) == [schema]
    assert schema.read_text(encoding="utf-8") == contract.schema_yaml()


def test_every_setting_says_what_it_means():
    def leaves(tree, prefix=""):
        for key, node in tree.items():
            if isinstance(node, contract.Section):
                yield from leaves(node.keys, f"{prefix}{key}.")
            else:
                yield f"{prefix}{key}", node

    for path, node in [*leaves(contract.RUN_SETTINGS), *leaves(contract.MACHINE_SETTINGS)]:
        assert node.doc.strip() and node.shown is not None, f"{path}: no meaning or default in docs"
        assert "default" not in node.schema, path  # defaults live in Setting.default only
        if isinstance(node.default, bool):  # a YAML literal, shown as code like the enums
            assert node.shown == f"`{str(node.default).lower()}`", path


@pytest.mark.parametrize(
    ("config", "where"),
    [
        ({"defaults": {"deploy": {"hold_s": -1}}}, "defaults.deploy.hold_s"),
        ({"machines": {"m": {"rank": {"treshold": 0.9}}}}, "machines.m.rank"),
        ({"on_bad_input": "ignore"}, "on_bad_input"),
    ],
)
def test_validate_config_names_the_key_jsonschema_refuses(config, where):
    with pytest.raises(SettingsError, match=rf"config.yaml: {re.escape(where)}: "):
        validate_config(config)
    validate_config(CONFIG)  # the shipped config passes


@pytest.mark.parametrize(("section", "key"), sorted(contract.RETIRED_SETTINGS))
@pytest.mark.parametrize("place", ["defaults", "machines.m"])
def test_a_retired_setting_is_refused_in_one_line_naming_what_replaced_it(section, key, place):
    assert key not in MACHINE_DEFAULTS[section]  # gone from the defaults, the schema, the docs
    assert f"`{section}.{key}`" not in (ROOT / "docs" / "settings.md").read_text(encoding="utf-8")
    block = {section: {key: True}}
    config = {"defaults": block} if place == "defaults" else {"machines": {"m": block}}
    with pytest.raises(SettingsError) as caught:
        validate_config(config)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(f"config.yaml: {place}.{section}.{key} was removed on 2026-11-29 (issue 49): ")
    assert message.endswith(contract.RETIRED_SETTINGS[(section, key)])


def test_the_workflow_refuses_a_retired_setting_with_its_line(tmp_path):
    import sys

    sys.path.insert(0, str(ROOT / "tests"))
    from project_copy import copy_project, run_snakemake

    proj = copy_project(tmp_path / "proj", config=False)
    config = {"defaults": {"models": {"interval_forward_units": True}}, "machines": {"m": None}}
    (proj / "config.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    done = run_snakemake(proj, "-n")
    assert done.returncode != 0
    assert (
        "RAFI: config.yaml: defaults.models.interval_forward_units was removed on 2026-11-29 (issue 49): "
        + contract.RETIRED_SETTINGS[("models", "interval_forward_units")]
    ) in done.stdout + done.stderr


def test_limits_and_replay_keys_come_from_the_contract():
    from dataclasses import fields

    from rafi.deploy.limits import Limits

    assert tuple(f.name for f in fields(Limits)) == contract.LIMIT_KEYS
    assert set(contract.REPLAY_KEYS) == {*contract.LIMIT_KEYS, "replay_roles"}


def _source_files():
    yield from (p for p in (ROOT / "rafi").rglob("*.py") if p.name not in ("settings.py", "contract.py"))
    yield from (ROOT / "workflow").rglob("*.py")
    yield from (ROOT / "workflow").rglob("*.smk")
    yield ROOT / "Snakefile"


def _read_keys() -> set[str]:
    """Names read as a key somewhere: ``x["key"]``, ``x.get("key")``, ``key=`` in a call, or
    ``smk.params.key`` (the workflow's params are named like the settings they carry)."""
    found: set[str] = set()
    for path in _source_files():
        text = path.read_text(encoding="utf-8")
        found |= set(re.findall(r"""\[\s*["'](\w+)["']\s*\]""", text))
        found |= set(re.findall(r"""\.get\(\s*["'](\w+)["']""", text))
        found |= set(re.findall(r"""\.params\.(\w+)""", text))
        if path.suffix == ".py":
            for node in ast.walk(ast.parse(text)):
                if isinstance(node, ast.keyword) and node.arg:
                    found.add(node.arg)
    return found


def test_every_key_the_schema_allows_is_read_somewhere():
    read = _read_keys()
    leaves = {path[-1] for path in schema_keys(SCHEMA["$defs"]["machine_settings"]) if path[0] != "input"}
    leaves |= {path[-1] for path in schema_keys(SCHEMA)}
    unread = sorted(leaves - read - {"defaults", "machines"})
    assert not unread, f"settings nothing reads: {unread}"


def test_layers_machine_over_defaults_over_built_in():
    config = {
        "defaults": {"qualification": {"max_residual_um": 9.0}, "report": {"figure_format": "svg"}},
        "machines": {"m1": {"qualification": {"min_improvement_pct": 50.0}}},
    }
    m1 = machine_settings(config, "m1")
    assert m1["qualification"] == {
        "max_residual_um": 9.0,
        "min_improvement_pct": 50.0,
        "never_worse_than_uncompensated": True,
        "min_coverage": None,
    }
    assert tuple(m1["qualification"]) == GATE_KEYS
    assert m1["report"]["figure_format"] == "svg"  # the bug: defaults.report was never read
    assert machine_settings(config, "m2")["qualification"]["min_improvement_pct"] == 30.0
    # lists replace, they do not merge
    assert deep_merge({"a": [1, 2], "b": {"c": 1}}, {"a": [3]}) == {"a": [3], "b": {"c": 1}}
    # a fresh copy every time
    m1["qualification"]["max_residual_um"] = 0
    assert machine_settings(config, "m1")["qualification"]["max_residual_um"] == 9.0
    assert MACHINE_DEFAULTS["qualification"]["max_residual_um"] == 12.0


def test_input_mapping_is_normalised_with_its_own_defaults():
    native = machine_settings({}, "m")["input"]
    assert native["format"] == "native" and native["pattern"] == "*.csv"
    xlsx = machine_settings({"machines": {"m": {"input": {"format": "xlsx"}}}}, "m")["input"]
    assert xlsx["pattern"] == "*.xlsx"  # not the native pattern of a merged default


@pytest.mark.parametrize("section", ["qualification", "models", "nightly", "report", "rank"])
def test_a_machine_section_at_the_top_level_is_refused_with_where_it_belongs(section):
    config = {**CONFIG, section: {}}
    with pytest.raises(
        SettingsError, match=rf"'{section}' is a per-machine setting: put it under 'defaults:'"
    ):
        check_layout(config)
    with pytest.raises(SettingsError):
        machine_settings(config, "tapping-center-a")
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(config, SCHEMA)


def test_an_unknown_top_level_key_is_refused():
    with pytest.raises(SettingsError, match="'raw_directory' is not a setting"):
        run_settings({"raw_directory": "x"})


def test_run_settings_defaults_and_overrides():
    assert run_settings({}) == RUN_DEFAULTS
    assert run_settings({"on_bad_input": "quarantine"})["on_bad_input"] == "quarantine"


def test_rafi_settings_prints_what_a_machine_gets(capsys, monkeypatch):
    from rafi.cli import main

    monkeypatch.chdir(ROOT)
    assert main(["settings", "--machine", "machining-center-b"]) == 0
    shown = yaml.safe_load(capsys.readouterr().out)
    assert shown == machine_settings(CONFIG, "machining-center-b")
    assert shown["sample_period_s"] == 15 and shown["qualification"]["max_residual_um"] == 12.0


def test_rafi_nightly_refuses_a_misplaced_section_with_the_message(tmp_path, capsys):
    from rafi.cli import main
    from rafi.ops.status import EXIT_USAGE

    (tmp_path / "config.yaml").write_text("qualification:\n  max_residual_um: 5.0\n", encoding="utf-8")
    assert main(["nightly", "--directory", str(tmp_path)]) == EXIT_USAGE
    assert "'qualification' is a per-machine setting" in capsys.readouterr().err


def test_the_workflow_names_the_key_of_a_machine_setting_the_schema_refuses(tmp_path):
    """Snakemake's own validation reports a mistake under ``machines: <name>:`` only as "is not
    valid under any of the given schemas" with a dump of the whole machine section (the schema's
    ``anyOf`` of settings or null); planning names the key and the values accepted, in one line."""
    import sys

    sys.path.insert(0, str(ROOT / "tests"))
    from project_copy import copy_project, run_snakemake

    proj = copy_project(tmp_path / "proj", config=False)
    bad = {"machines": {"m": {"input": {"format": "csv", "pattern": "*.csv", "temperature_unit": "R"}}}}
    (proj / "config.yaml").write_text(yaml.safe_dump(bad), encoding="utf-8")
    done = run_snakemake(proj, "-n")
    out = done.stdout + done.stderr
    assert done.returncode != 0
    assert "RAFI: config.yaml: machines.m.input.temperature_unit: 'R' is not one of ['C', 'K', 'F']" in out
    assert "not valid under any of the given schemas" not in out


SECRET = "hunter2-Xq7"


@pytest.mark.parametrize("debug", [[], ["--debug"]])
def test_rafi_settings_never_prints_a_credential_and_says_the_config_is_refused(tmp_path, capsys, debug):
    from rafi.cli import main

    opcua = {"endpoint": f"opc.tcp://bob:{SECRET}@10.0.0.5:4840", "password": SECRET, "User": "bob"}
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump({"machines": {"m1": {"deploy": {"opcua": opcua}}}}))
    assert main([*debug, "settings", "--machine", "m1", "--config", str(path)]) == 64
    out, err = capsys.readouterr()
    assert SECRET not in out + err and "bob" not in out + err
    shown = yaml.safe_load(out)["deploy"]["opcua"]
    assert shown == {"endpoint": "opc.tcp://***@10.0.0.5:4840", "password": "***", "User": "***"}
    assert err.count("\n") == 1
    assert re.search(r"machines\.m1\.deploy\.opcua\.\w+ \(and 2 more\) holds a credential", err)
    assert "rafi deploy and rafi record refuse this config" in err
    # a schema error that quotes a block with a credential in it
    path.write_text(yaml.safe_dump({"machines": {"m1": {"deploy": {"interval_s": {"password": SECRET}}}}}))
    assert main([*debug, "settings", "--machine", "m1", "--config", str(path)]) == 2
    out, err = capsys.readouterr()
    assert SECRET not in out + err and "machines.m1.deploy.interval_s: {'password': '***'}" in err


@pytest.mark.parametrize("debug", [[], ["--debug"]])
def test_rafi_deploy_refuses_a_credential_in_config_yaml_without_printing_it(tmp_path, capsys, debug):
    from test_live import artefact, make_registry

    from rafi.cli import main

    make_registry(tmp_path / "results" / "m1" / "registry", artefact())
    for opcua in (
        {"endpoint": "opc.tcp://10.0.0.5:4840", "password": SECRET},
        {"endpoint": f"opc.tcp://bob:{SECRET}@10.0.0.5:4840"},
        {"endpoint": f"http://bob:{SECRET}@10.0.0.5:4840"},
    ):
        deploy = {"opcua": opcua, "target": {"kind": "csv", "axis": "Z", "path": "out.csv"}}
        path = tmp_path / "config.yaml"
        path.write_text(yaml.safe_dump({"machines": {"m1": {"deploy": deploy}}}))
        assert main([*debug, "deploy", "--machine", "m1", "--config", str(path), "--cycles", "1"]) == 64
        out, err = capsys.readouterr()
        assert SECRET not in out + err and "bob" not in out + err
        assert "deploy.opcua.endpoint" in err or "deploy.opcua.password: credentials never go" in err


@given(
    st.lists(st.text(alphabet="abc-_.+()[]@x1", min_size=1, max_size=6), max_size=5, unique=True),
    st.text(alphabet="abc-_.+()[]@x1", max_size=7),
)
def test_one_of_pattern_matches_exactly_its_names(names, other):
    """The folder constraint of the several-probes report: every name and nothing else, escaped
    (a name may be a prefix of another or hold regex characters); none: matches nothing."""
    pattern = one_of_pattern(names)
    for name in names:
        assert re.fullmatch(pattern, name)
    assert bool(re.fullmatch(pattern, other)) == (other in names)
