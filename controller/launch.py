"""``fishfarm``'s entry point (pyproject's ``[project.scripts]``): SIGINT and SIGTERM are taken
before anything is imported, then ``controller.cli.entry`` runs the command with its own handlers.

The command's imports (click, the command's modules) take a tenth of a second and more: a Ctrl-C
in that time printed a 17-line KeyboardInterrupt traceback from inside ``import click`` and exited
-2. Nothing has started then, so nothing needs cleaning up: the early handler says "aborted" and
exits as a command interrupted later does (130 for SIGINT, 143 for SIGTERM).
"""
import os
import signal


def _early(signum, _frame) -> None:
    try:
        os.write(2, b"fishfarm: aborted\n")
    finally:
        os._exit(128 + signum)        # mid-import: no exception may unwind through the import machinery


def entry() -> None:
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:   # not a background job's ignored one
        signal.signal(signal.SIGINT, _early)
    signal.signal(signal.SIGTERM, _early)
    from controller.cli import entry as command
    command()


if __name__ == "__main__":
    entry()
