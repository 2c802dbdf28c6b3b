"""``fishfarm`` command line. Each command lives in its own module, imported only when run,
so ``fishfarm demand`` does not pay for OpenCV and ``fishfarm survey`` does not load Zenoh."""
from __future__ import annotations

import _thread
import importlib
import os
import signal
import sys

import click

from controller.errors import BadInput
from controller.launch import simulating, stop_code

# command name -> "module:attribute" of a click command
COMMANDS = {
    "run": "controller.cli.run_cmd:run",
    "sim": "controller.cli.sim_cmd:sim",
    "calibrate": "controller.cli.calibrate_cmd:calibrate",
    "triangulate": "controller.cli.triangulate_cmd:triangulate",
    "survey": "controller.cli.survey_cmd:survey",
    "demand": "controller.cli.demand_cmd:demand",
    "track": "controller.cli.track_cmd:track",
    "override": "controller.cli.override_cmd:override",
    "status": "controller.cli.override_cmd:status",
    "credentials": "controller.cli.credentials_cmd:credentials",
    "audit": "controller.cli.audit_cmd:audit",
    "cleaner": "controller.cli.cleaner_cmd:cleaner",
    "report": "controller.cli.report_cmd:report",
    "history": "controller.cli.history_cmd:history",
    "worker": "controller.cli.worker_cmd:worker",
    "clock": "controller.cli.clock_cmd:clock",
}


class CheckedGroup(click.Group):
    """A group whose subcommands' options are checked first (``refuse_repeated``)."""

    def resolve_command(self, ctx, args):
        name, cmd, rest = super().resolve_command(ctx, args)
        if cmd is not None and not ctx.resilient_parsing:
            refuse_repeated(ctx, name, cmd, rest)
        return name, cmd, rest


class LazyGroup(CheckedGroup):
    """A group whose subcommands are ``name -> "module:attr"`` in ``table``, imported on use."""

    table = COMMANDS

    def list_commands(self, ctx):
        return sorted(name for name in self.table if self._target(name) is not None)

    def get_command(self, ctx, name):
        return self._target(name)

    def _target(self, name):
        spec = self.table.get(name)
        if spec is None:
            return None
        module, attr = spec.split(":")
        try:
            return getattr(importlib.import_module(module), attr)
        except ModuleNotFoundError as exc:
            if exc.name == module:  # not written yet
                return None
            raise


def refuse_repeated(ctx: click.Context, name: str, cmd: click.Command, args: list[str]) -> None:
    """Refuse, naming the option, what click would take silently: an option of one value given twice
    (the last kept: ``--video A B --video C D`` surveyed C D alone) and one of the command's own
    options read as another's value (``--video LEFT --json OUT``: --json taken for RIGHT, then
    "Missing option '--json'")."""
    probe = click.Context(cmd, info_name=name, parent=ctx, resilient_parsing=True)
    try:
        opts, _, order = cmd.make_parser(probe).parse_args(args=list(args))
    except click.UsageError:
        return                                   # click's own pass says what is wrong
    if getattr(cmd, "takes_anything", lambda _args: False)(args):
        # a command that must act whatever it is given (``fishfarm override estop``): said, not refused
        for flag in _repeated(order):
            click.echo(f"fishfarm {name}: {flag} given more than once: the last is sent, the others left out",
                       err=True)
        return
    names = {o for p in cmd.get_params(probe) if isinstance(p, click.Option) for o in (*p.opts, *p.secondary_opts)}
    seen: set[str] = set()
    for param in order:
        if not isinstance(param, click.Option) or param.is_flag or param.count:
            continue
        flag = max(param.opts, key=len)
        if param.name in seen and not param.multiple:
            raise click.BadOptionUsage(flag, f"{flag} given more than once: give it once (only one would be used)",
                                       ctx=probe)
        seen.add(param.name)
        # a repeatable option's values too (``--pair L --json OUT``: --json taken for R)
        for v in _flat(opts.get(param.name)):
            if isinstance(v, str) and v in names:
                what = " ".join(param.metavar.split()) if param.metavar else f"{param.nargs} value(s)"
                raise click.BadOptionUsage(flag, f"{flag} takes {what}: {v} is an option, not its value", ctx=probe)


def _repeated(order) -> list[str]:
    """The single-value options given more than once in a parse's ``order``, by their long names."""
    once = [p for p in order if isinstance(p, click.Option) and not (p.is_flag or p.multiple or p.count)]
    return sorted({max(p.opts, key=len) for p in once if once.count(p) > 1})


def _flat(value) -> list:
    """An option's parsed value as a flat list: one value, a tuple of nargs, a list of those."""
    if isinstance(value, (tuple, list)):
        return [v for item in value for v in _flat(item)]
    return [value]


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
def cli():
    """Fish-farm automation controller."""


def main(argv=None) -> int:
    """Entry point. Bad input: one line on stderr, exit 2. Never a traceback for the user's mistake."""
    try:
        rv = cli.main(args=argv, prog_name="fishfarm", standalone_mode=False)
        return rv if isinstance(rv, int) else 0
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except click.exceptions.Abort:
        click.echo("fishfarm: aborted", err=True)
        return 130
    except click.ClickException as exc:
        ctx = getattr(exc, "ctx", None)
        cmd = f" {ctx.command_path.split(' ', 1)[-1]}" if ctx is not None and ctx.parent else ""
        click.echo(f"fishfarm{cmd}: {exc.format_message()}", err=True)
        return 2
    except BadInput as exc:
        click.echo(f"fishfarm: {exc}", err=True)
        return 2
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # a bug, not the user's fault: still one line unless asked
        if _signalled is not None:    # a signal's exception turned into another on its way (below)
            return _signalled
        if os.environ.get("FISHFARM_DEBUG"):
            raise
        click.echo(f"fishfarm: internal error: {type(exc).__name__}: {exc}", err=True)
        return 1


def _interrupted(signum, frame) -> None:
    """Ctrl-C as Python's own, except that a second one ends the command at once (its default
    action), rather than a KeyboardInterrupt in the middle of the first one's clean-up printing a
    traceback as the interpreter ends."""
    if _in_hook(frame):
        _take_again(signum)
        return
    signal.signal(signum, signal.SIG_DFL)
    raise _taken(KeyboardInterrupt(), signum, _interrupted)


def _terminated(signum, frame) -> None:
    """SIGTERM ends a command as Ctrl-C does, through its clean-up (a survey's workers stopped, no
    half-written output left); a second one ends it at once. Commands that serve (run, sim,
    worker) install their own handlers over this one once they start, SIGHUP's too: ``run`` and
    ``sim`` wake the loop for the orderly stop (controller/shutdown.py), raising nothing. Until
    then SIGHUP is this one as well (its default killed a starting controller without a word,
    its ledger's -wal left behind, an outside tester); nohup's ignored SIGHUP stays ignored."""
    if _in_hook(frame):
        _take_again(signum)
        return
    signal.signal(signum, signal.SIG_DFL)
    raise _taken(SystemExit(stop_code(signum)), signum, _terminated)


# The exit code of the first signal whose exception was raised. A SIGHUP as a command
# imported its modules raised its SystemExit inside an extension's initialisation (OpenCV's, ONNX
# Runtime's, matplotlib's: pybind11's), which replaced it with "ImportError: initialization
# failed": the command ended as an internal error, exit 1.
_signalled: int | None = None


def _taken(exc: BaseException, signum: int, handler) -> BaseException:
    global _signalled
    exc.fishfarm_signal = (signum, handler)
    if _signalled is None:
        _signalled = 130 if isinstance(exc, KeyboardInterrupt) else exc.code
    return exc


def _swallowed(unraisable) -> None:
    """``sys.unraisablehook``: a signal's exception raised where Python can raise none (a weakref
    callback, a ``__del__``; the import machinery's module locks have such callbacks) was printed
    as "Exception ignored in" with its traceback, and lost: a SIGHUP as ``report`` imported its
    modules let it run on to its end (CI). The signal is taken again, its handler back in place,
    at a line that can raise: however often it falls where none can, it comes back."""
    signum, handler = getattr(unraisable.exc_value, "fishfarm_signal", (None, None))
    if signum is None:
        sys.__unraisablehook__(unraisable)
        return
    signal.signal(signum, handler)
    _take_again(signum)


def _take_again(signum: int) -> None:
    # From another thread: from this one the handler runs at once, still inside the hook, where
    # its exception would be lost as well. Should it run there even so, it sends itself again.
    _thread.start_new_thread(_thread.interrupt_main, (signum,))


def _in_hook(frame) -> bool:
    while frame is not None:
        if frame.f_code is _swallowed.__code__:
            return True
        frame = frame.f_back
    return False


# OpenCV's and FFmpeg's own lines ("[ WARN:4@15.707] global cap_ffmpeg_impl.hpp:435 ... Stream
# timeout triggered", "[tcp @ 0x...] Connection refused") went straight to the terminal, with no
# time stamp, every second a camera was lost, through the live console table; our log says when a
# camera is lost and back. Errors of OpenCV's own still print. OpenCV reads these when it loads or
# opens its first capture; a user who sets them gets what they ask for.
NATIVE_LOGS = {"OPENCV_LOG_LEVEL": "ERROR", "OPENCV_FFMPEG_LOGLEVEL": "-8"}     # -8: AV_LOG_QUIET


def _early_handler():
    from controller.launch import _early  # the launcher's, while the command was imported
    return _early


def entry() -> None:
    for name, value in NATIVE_LOGS.items():     # before any command imports cv2 (the controller,
        os.environ.setdefault(name, value)      # its simulator and survey workers all start here)
    take_signals()
    sys.exit(main())


def take_signals() -> None:
    """The command's handlers of SIGTERM, SIGHUP and SIGINT, over the launcher's early ones."""
    sys.unraisablehook = _swallowed
    signal.signal(signal.SIGTERM, _terminated)
    if signal.getsignal(signal.SIGHUP) in (signal.SIG_DFL, _early_handler()):
        signal.signal(signal.SIGHUP, _terminated)
    if signal.getsignal(signal.SIGINT) in (signal.default_int_handler, _early_handler()):
        # (not a background job's ignored one; the simulator's ends it with 0, as SIGTERM does)
        signal.signal(signal.SIGINT, _terminated if simulating() else _interrupted)


if __name__ == "__main__":
    entry()
