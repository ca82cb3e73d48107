"""The prior's id in a ``checks.confirmed`` entry, as printed and as read back (issue 47).

The entries the pipeline prints for a fitness warning left the prior's id unquoted
(``{file: 6fca63e8ad59, check: prior_speeds}``). A model id is hex: its first 12 characters are
all digits about once in 300 ids (``(10/16) ** 12``), and YAML then reads the pasted entry as a
number (``yaml.safe_load('{file: 012345670123}')`` is an octal int, ``123456789012`` a decimal
one), which the schema (``file``: a string) refuses. Every printed entry now quotes the id as the
input warnings' entries quote the file name (``json.dumps``), and the settings reader takes back
an id written unquoted where the number can only be that id (12 or 64 decimal digits), or names
the fix in one line.
"""

from __future__ import annotations

import pytest
import yaml

from rafi.errors import SettingsError
from rafi.family.confirmation import awaiting_confirmation, confirmation_entries, unquoted_ids

DIGITS = "012345670123" + "9" * 52  # a prior id whose first 12 characters are digits 0-7: octal in YAML
DECIMAL = "123456789012" + "a" * 52


def _waiting(prior: str) -> dict:
    blocking = [{"check": "prior_speeds", "prior": prior, "machine": "a", "for_machine": "a"}]
    return {
        "decision": "rejected",
        "gates_passed": True,
        "blocked_by": ["prior_fitness"],
        "prior_fitness": {"blocking": blocking, "confirmed": []},
    }


@pytest.mark.parametrize("prior", [DIGITS, DECIMAL, "6fca63e8ad59" + "0" * 52])
def test_every_printed_entry_reads_back_as_the_priors_id(prior):
    from rafi.ops.provenance import prior_warning_reason
    from rafi.report.requalification_section import fitness_context

    (entry,) = confirmation_entries(_waiting(prior))
    assert entry == f'{{file: "{prior[:12]}", check: prior_speeds}}'
    assert yaml.safe_load(entry) == {"file": prior[:12], "check": "prior_speeds"}
    assert f"[{entry}]" in awaiting_confirmation(_waiting(prior))
    reason = prior_warning_reason({"prior": prior, "machine": "a", "check": "prior_speeds", "message": "m"})
    assert f"({entry})" in reason
    block = {
        "fitness": {"prior": {"model_id": prior}, "warnings": [{"check": "prior_speeds", "message": "m"}]}
    }
    assert fitness_context(block, "a")["warnings"][0]["confirm"] == entry


def _config(entry: str) -> dict:
    return yaml.safe_load(f"machines:\n  a:\n    checks:\n      confirmed: [{entry}]\n")


def test_an_id_written_unquoted_is_read_back_where_the_number_can_only_be_that_id():
    config = _config("{file: 123456789012, check: prior_speeds}")
    assert config["machines"]["a"]["checks"]["confirmed"][0]["file"] == 123456789012  # what YAML reads
    assert unquoted_ids(config) == ["machines.a.checks.confirmed[0].file: 123456789012"]
    assert config["machines"]["a"]["checks"]["confirmed"][0]["file"] == "123456789012"
    full = _config("{file: " + "1" * 64 + ", check: prior_speeds}")
    unquoted_ids(full)
    assert full["machines"]["a"]["checks"]["confirmed"][0]["file"] == "1" * 64
    # quoted, a glob, a file name: untouched
    same = _config('{file: "012345670123", check: prior_speeds}, {file: "*.csv", check: speed_range}')
    assert unquoted_ids(same) == [] and same == _config(
        '{file: "012345670123", check: prior_speeds}, {file: "*.csv", check: speed_range}'
    )
    defaults = yaml.safe_load(
        "defaults:\n  checks:\n    confirmed: [{file: 123456789012, check: prior_misfit}]\n"
    )
    assert unquoted_ids(defaults) == ["defaults.checks.confirmed[0].file: 123456789012"]


def test_an_id_yaml_changed_is_refused_in_one_line_naming_the_fix():
    config = _config("{file: 012345670123, check: prior_speeds}")  # octal: the digits are lost
    value = config["machines"]["a"]["checks"]["confirmed"][0]["file"]
    assert value == int("12345670123", 8)
    with pytest.raises(SettingsError) as err:
        unquoted_ids(config)
    message = str(err.value)
    assert "\n" not in message
    assert f"machines.a.checks.confirmed[0].file: {value}" in message
    assert 'quote it: {file: "<the id as printed>", check: prior_speeds}' in message


def test_the_project_config_reads_an_unquoted_id(tmp_path):
    from rafi.ops.project import load_config

    (tmp_path / "config.yaml").write_text(
        "machines:\n  a:\n    checks:\n      confirmed: [{file: 123456789012, check: prior_speeds}]\n",
        encoding="utf-8",
    )
    config = load_config(tmp_path, "config.yaml")
    assert config["machines"]["a"]["checks"]["confirmed"] == [
        {"file": "123456789012", "check": "prior_speeds"}
    ]


def test_rafi_settings_and_rafi_plan_read_an_unquoted_id_as_the_pipeline_does(tmp_path, capsys):
    """``rafi settings`` refused the entry the pipeline takes back ("is not of type 'string'"):
    every command now reads config.yaml through the one reader, which takes the id back and says
    so once."""
    from argparse import Namespace

    from rafi import settings

    path = tmp_path / "config.yaml"
    path.write_text(
        "machines:\n  a:\n    checks:\n      confirmed: [{file: 123456789012, check: prior_speeds}]\n",
        encoding="utf-8",
    )
    assert settings.run(Namespace(config=str(path), machine="a")) == 0
    out, err = capsys.readouterr()
    shown = yaml.safe_load(out)
    assert shown["checks"]["confirmed"] == [{"file": "123456789012", "check": "prior_speeds"}]
    assert err.count("read as the prior's id '123456789012'; quote it in config.yaml") == 1
    config, machine = settings.read_machine_config(path, "a")
    assert machine["checks"]["confirmed"][0]["file"] == "123456789012"
    assert settings.read_config(path, say=False) == config and capsys.readouterr().err.count("quote it") == 1


def test_a_config_that_is_not_yaml_is_one_line_naming_the_file(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text("machines: [a\n", encoding="utf-8")
    with pytest.raises(SettingsError, match=r"config\.yaml: cannot read the config"):
        from rafi.ops.project import load_config

        load_config(tmp_path, "config.yaml")
