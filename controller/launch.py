"""``fishfarm``'s entry point (pyproject's ``[project.scripts]``, and ``python -m controller.launch``,
which the controller starts its simulator with): SIGINT, SIGTERM and SIGHUP are taken before anything
is imported, then ``controller.cli.entry`` runs the command with its own handlers. (``python -m
controller.cli`` imports the package, click and all, before any line of ours runs.)

The command's imports (click, the command's modules) take a tenth of a second and more: a Ctrl-C
in that time printed a 17-line KeyboardInterrupt traceback from inside ``import click`` and exited
-2. Nothing has started then, so nothing needs cleaning up: the early handler says "aborted" and
exits as a command interrupted later does (130 for SIGINT, 143 for SIGTERM; ``fishfarm sim`` 0, as
a signal ends it whatever it is doing). Only the interpreter's own start, before any program runs,
is out of reach.
"""
import _signal  # the C module: ``signal`` builds its enums first, and a Ctrl-C there was a traceback
import os  # (imported already, by site)
import sys  # (built in)


def simulating() -> bool:
    """Whether the command is ``fishfarm sim``, which README says a signal ends with 0 whatever it is
    doing (in its first second it exited 130, 143 or 129)."""
    return sys.argv[1:2] == ["sim"]


def stop_code(signum: int) -> int:
    """The exit code of a command a signal ends before it takes the signal itself: 128 + signum,
    but 0 for the simulator."""
    return 0 if simulating() else 128 + signum


def _early(signum, _frame) -> None:
    code = stop_code(signum)
    try:
        os.write(2, b"fishfarm: aborted\n" if code else b"fishfarm sim: stopped while starting\n")
    finally:
        os._exit(code)        # mid-import: no exception may unwind through the import machinery


def entry() -> None:
    if _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler:   # not a background job's ignored one
        _signal.signal(_signal.SIGINT, _early)
    _signal.signal(_signal.SIGTERM, _early)
    if _signal.getsignal(_signal.SIGHUP) == _signal.SIG_DFL:    # not nohup's ignored one
        _signal.signal(_signal.SIGHUP, _early)    # (its default killed a starting controller: no word)
    from controller.cli import entry as command
    command()


if __name__ == "__main__":
    entry()
