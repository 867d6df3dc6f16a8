"""The command group loads a command's module only when that command is asked for; its --help lists
every command as click would from the loaded commands."""

from __future__ import annotations

import importlib

import click
import pytest

from fmcwlog.cli import COMMANDS, LazyGroup, cli


def _loaded(name: str) -> click.Command:
    module, attribute, _ = COMMANDS[name]
    return getattr(importlib.import_module(f"fmcwlog.cli.{module}"), attribute)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_each_listed_summary_is_the_first_paragraph_of_the_commands_help(name):
    cmd = _loaded(name)
    assert cmd.name == name and not cmd.hidden and not cmd.deprecated and cmd.short_help is None
    first = (cmd.help or "").partition("\n\n")[0]  # what click's short help is made of
    assert " ".join(first.split()) == " ".join(COMMANDS[name][2].split())


@pytest.mark.parametrize("width", [40, 60, 80, 100, 200])
def test_the_listing_is_clicks_own_from_the_loaded_commands(width):
    """The group's help before any command is loaded, and after, equals a plain click group's."""
    plain = click.Group("fmcwlog", commands={name: _loaded(name) for name in COMMANDS}, help=cli.help,
                        params=cli.params, context_settings=cli.context_settings)
    lazy = LazyGroup("fmcwlog", help=cli.help, params=cli.params, context_settings=cli.context_settings)

    def page(group: click.Group) -> str:
        with click.Context(group, info_name="fmcwlog", terminal_width=width, max_content_width=width) as ctx:
            return group.get_help(ctx)

    expected = page(plain)
    assert "Commands:" in expected and all(name in expected for name in COMMANDS)
    assert page(lazy) == expected  # nothing loaded yet
    assert not lazy.commands
    with click.Context(lazy) as ctx:
        lazy.get_command(ctx, "process")
    assert set(lazy.commands) == {"process"} and page(lazy) == expected  # one loaded, the others not


def test_an_unknown_command_is_none_and_lists_nothing_new():
    with click.Context(cli) as ctx:
        assert cli.get_command(ctx, "nope") is None
        assert cli.list_commands(ctx) == sorted(COMMANDS)


def test_a_mistyped_command_is_suggested_from_every_command_loaded_or_not():
    with pytest.raises(click.exceptions.NoSuchCommand) as raised:
        LazyGroup("fmcwlog").main(["calibrat"], standalone_mode=False)
    assert raised.value.format_message() == "No such command 'calibrat'. Did you mean 'calibrate'?"


def test_shell_completion_offers_every_command(monkeypatch, capsys):
    monkeypatch.setenv("_FMCWLOG_COMPLETE", "bash_complete")
    monkeypatch.setenv("COMP_WORDS", "fmcwlog ")
    monkeypatch.setenv("COMP_CWORD", "1")
    with pytest.raises(SystemExit):
        LazyGroup("fmcwlog").main([], prog_name="fmcwlog", complete_var="_FMCWLOG_COMPLETE")
    offered = [line.split(",")[1] for line in capsys.readouterr().out.splitlines()]
    assert offered == sorted(COMMANDS)
