"""``fishfarm credentials``: the Zenoh user/password file of a deployment, with random passwords.

No password ships with the project: this writes them. The file is zenoh's ``dictionary_file``
(config/zenoh/deploy.json5): one ``user:password`` a line, nothing else (zenoh 1.10 rejects
comments and blank lines), readable by its owner only. A user's role is the ACL subject listing
their name in deploy.json5.
"""
from __future__ import annotations

import os
import secrets
from pathlib import Path

import click

from controller.errors import BadInput
from controller.identity import USER

DEFAULT_OUT = "config/zenoh/credentials.txt"
USERS = ("controller", "engineer", "operator", "viewer", "worker")
PASSWORD_BYTES = 18      # 24 characters of [A-Za-z0-9_-]: 144 random bits


def new_password() -> str:
    """Never starting with '-': it would read as an option after --password."""
    while (password := secrets.token_urlsafe(PASSWORD_BYTES))[0] == "-":
        pass
    return password


def read(path: Path) -> dict[str, str]:
    """The file as {user: password}; BadInput naming the line of a malformed one."""
    entries: dict[str, str] = {}
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        user, colon, password = line.partition(":")
        if not colon or not USER.match(user) or not password:
            raise BadInput(str(path), f"line {number}", "expected user:password (zenoh allows nothing else)")
        if user in entries:
            raise BadInput(str(path), f"line {number}", f"user {user!r} given twice")
        entries[user] = password
    return entries


def write(path: Path, entries: dict[str, str]) -> None:
    """Atomically, mode 0600 from the first byte: a reader sees the old file or the whole new one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write("".join(f"{user}:{password}\n" for user, password in entries.items()))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _name(value: str) -> str:
    if not USER.match(value):
        raise BadInput("--add", None, f"{value[:80]!r}: user names are letters, digits, _ . - (1 to 64)")
    return value


@click.command()
@click.option("--out", "out", default=DEFAULT_OUT, show_default=True, type=click.Path(dir_okay=False),
              help="the credentials file (deploy.json5's dictionary_file).")
@click.option("--add", "add", multiple=True, metavar="NAME",
              help="add a user with a new random password to the file (repeatable); prints NAME:PASSWORD.")
@click.option("--force", is_flag=True, help="replace an existing file: every password changes.")
def credentials(out, add, force):
    """Write random passwords for controller, engineer, operator, viewer and worker (or --add people).

    Then list each person's user name in their role's subject in config/zenoh/deploy.json5.
    """
    from controller.cli.output_paths import check_outputs
    check_outputs({"--out": out}, [])
    path = Path(out)
    if add:
        names = [_name(n) for n in add]
        entries = read(path) if path.exists() else {}
        for name in names:
            if names.count(name) > 1:
                raise BadInput("--add", None, f"{name!r} given more than once: one user, one password")
            if name in entries:
                raise BadInput(str(path), name, "user exists already (remove its line to replace it)")
        added = {name: new_password() for name in names}
        write(path, {**entries, **added})
        for name, password in added.items():
            click.echo(f"{name}:{password}")
        return 0
    if path.exists() and not force:
        raise BadInput(str(path), None, "exists already (--force replaces every password, --add NAME adds one)")
    write(path, {user: new_password() for user in USERS})
    click.echo(f"wrote {path}: {', '.join(USERS)} (mode 0600)", err=True)
    return 0
