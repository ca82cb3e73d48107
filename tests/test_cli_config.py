"""Issue 45: one spelling of the config option on every ``rafi`` command (``--config``), with
``--config-file`` kept as a hidden alias."""

from __future__ import annotations

import pytest

from rafi.cli import CONFIG_ALIAS, CONFIG_OPTION, build_parser

#: Every command that reads the pipeline config, with the arguments it needs besides.
COMMANDS = {
    "settings": [],
    "status": [],
    "nightly": [],
    "plan": ["--machine", "m"],
    "record": ["--machine", "m"],
    "deploy": ["--machine", "m"],
    "replay": ["--machine", "m"],
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
@pytest.mark.parametrize("option", [CONFIG_OPTION, CONFIG_ALIAS])
def test_every_command_takes_both_spellings_into_args_config(command, option):
    parser = build_parser()
    args = parser.parse_args([command, *COMMANDS[command], option, "other.yaml"])
    assert args.config == "other.yaml"
    assert parser.parse_args([command, *COMMANDS[command]]).config == "config.yaml"


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_help_shows_config_and_hides_the_alias(command, capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args([command, "--help"])
    text = capsys.readouterr().out
    assert f"{CONFIG_OPTION} CONFIG" in text
    assert CONFIG_ALIAS not in text


def test_no_command_has_a_config_option_of_its_own_spelling():
    """Any other option with 'config' in its name would be a third spelling."""
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name, command in sub.choices.items():
        strings = {s for action in command._actions for s in action.option_strings if "config" in s}
        assert strings <= {CONFIG_OPTION, CONFIG_ALIAS}, (name, strings)


def test_a_reader_that_closes_the_pipe_early_gets_no_traceback():
    """``rafi settings ... | head -1``: the command stops quietly with 141 (128 + SIGPIPE)."""
    import subprocess
    import sys
    from pathlib import Path

    from rafi.cli import EXIT_BROKEN_PIPE

    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen(
        [sys.executable, "-m", "rafi.cli", "settings", "--machine", "tapping-center-a"],
        cwd=root,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()  # before the command writes anything: its first write meets a closed pipe
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == EXIT_BROKEN_PIPE
    assert "Traceback" not in err and "BrokenPipeError" not in err
