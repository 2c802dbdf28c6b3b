"""Options click would take silently, refused naming them (controller.cli.refuse_repeated), for every
command: one of a single value given twice (click kept the last: ``--video A B --video C D``
surveyed C D alone, exit 0) and a command's own option read as another's value (``--video LEFT
--json OUT``: --json taken for RIGHT, then "Missing option '--json'")."""
from __future__ import annotations

import click
import pytest

from controller.cli import COMMANDS, CheckedGroup, cli, main


def _commands() -> list[tuple[list[str], click.Command]]:
    """(argv prefix, command) of every command and every subcommand of a lazy group."""
    out = []

    def walk(prefix, group):
        ctx = click.Context(group)
        for name in group.list_commands(ctx):
            cmd = group.get_command(ctx, name)
            if isinstance(cmd, click.Group):
                assert isinstance(cmd, CheckedGroup), f"{name}: a group whose options go unchecked"
                walk([*prefix, name], cmd)
            else:
                out.append(([*prefix, name], cmd))
    walk([], cli)
    return out


def _single_value_options() -> list[tuple[list[str], click.Option]]:
    return [(prefix, p) for prefix, cmd in _commands() for p in cmd.params
            if isinstance(p, click.Option) and not (p.is_flag or p.multiple or p.count)]


CASES = _single_value_options()
REPEATABLE = [(prefix, p) for prefix, cmd in _commands() for p in cmd.params
              if isinstance(p, click.Option) and p.multiple and not (p.is_flag or p.count)]


def test_every_command_is_looked_at():
    names = {tuple(prefix) for prefix, _ in _commands()}
    assert {(n,) for n in COMMANDS if n not in ("calibrate", "cleaner")} <= names and ("cleaner", "map") in names
    assert {("calibrate", m) for m in ("dlt", "chessboard", "import", "tower")} <= names
    assert len(CASES) > 50


@pytest.mark.parametrize("prefix, option", CASES, ids=[f"{' '.join(p)} {o.opts[-1]}" for p, o in CASES])
def test_an_option_of_one_value_given_twice_is_refused_naming_it(prefix, option, capsys):
    flag = max(option.opts, key=len)
    values = ["1"] * option.nargs
    code = main([*prefix, flag, *values, option.opts[0], *values])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f"fishfarm {' '.join(prefix)}: {flag} given more than once: give it once "
                                 "(only one would be used)"]


@pytest.mark.parametrize("prefix, option", CASES, ids=[f"{' '.join(p)} {o.opts[-1]}" for p, o in CASES])
def test_an_option_read_as_another_s_value_is_refused_naming_the_first(prefix, option, capsys):
    cmd = dict((tuple(p), c) for p, c in _commands())[tuple(prefix)]
    other = next(o for p in cmd.params if isinstance(p, click.Option) and p is not option for o in p.opts)
    flag = max(option.opts, key=len)
    code = main([*prefix, flag, *["1"] * (option.nargs - 1), other, "x"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0].startswith(f"fishfarm {' '.join(prefix)}: {flag} takes ") and f": {other} is an option, not " \
        "its value" in err[0]


@pytest.mark.parametrize("prefix, option", REPEATABLE, ids=[f"{' '.join(p)} {o.opts[-1]}" for p, o in REPEATABLE])
def test_an_option_read_as_a_repeatable_one_s_value_is_refused_naming_it(prefix, option, capsys):
    """``--pair L --json OUT``: --json was taken for R, then "Missing option '--json'"."""
    cmd = dict((tuple(p), c) for p, c in _commands())[tuple(prefix)]
    other = next(o for p in cmd.params if isinstance(p, click.Option) and p is not option for o in p.opts)
    flag = max(option.opts, key=len)
    code = main([*prefix, flag, *["1"] * option.nargs, flag, *["1"] * (option.nargs - 1), other, "x"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0].startswith(f"fishfarm {' '.join(prefix)}: {flag} takes ") and f": {other} is an option, not " \
        "its value" in err[0]


def test_repeatable_options_stay_repeatable(tmp_path, capsys):
    missing = [str(tmp_path / n) for n in ("a.png", "b.png", "c.png", "d.png")]
    code = main(["survey", "--calib", str(tmp_path / "c.json"), "--species", "sparus_aurata", "--setup", "underwater",
                 "--pair", *missing[:2], "--pair", *missing[2:], "--json", str(tmp_path / "o.json")])
    err = capsys.readouterr().err
    assert code == 2 and "more than once" not in err and "is an option" not in err


def test_a_value_that_only_looks_like_an_option_is_a_value(tmp_path, capsys):
    main(["survey", "--calib", "--not-an-option", "--species", "sparus_aurata", "--setup", "underwater",
          "--pair", "a", "b", "--json", str(tmp_path / "o.json")])
    err = capsys.readouterr().err
    assert "is an option" not in err and "--not-an-option" in err
