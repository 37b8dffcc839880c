"""The ``pendsim`` command line: the parser of every command (``pendsim_bridge.commands``) and the
one place where errors a user can fix become one line ``pendsim: error: ...`` and exit code 2."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from collections.abc import Iterator, Sequence

from pendsim_mj import __version__, compile_notice
from pendsim_mj.errors import ParameterError, PendsimError

from . import heap
from .io.outputs import describe_os_error, replace_hint_as
from .options import Parser, UsageError, explained
from .signals import interrupts_deferred, signal_handlers

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT
EXIT_TERMINATED = 143  # 128 + SIGTERM


class Terminated(BaseException):
    """SIGTERM or SIGHUP arrived: unwound like Ctrl-C, so that temporary files are removed and
    child processes ended on the way out."""


def build_parser() -> Parser:
    """The ``pendsim`` parser with every command's subparser (importing the commands' modules)."""
    from .commands import COMMANDS  # start-up: the commands load here, in main, with Ctrl-C deferred

    parser = Parser(
        prog="pendsim",
        description="Digital twin of the spring-coupled two-pendulum rig of Ganev et al., Machines 2025, 13(8), 660.",
        epilog="Units: angles in degrees at the command line, SI elsewhere. 'pendsim COMMAND --help' for details.",
    )
    parser.add_argument("--version", action="version", version=f"pendsim {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for command in COMMANDS:
        command.register(sub)
    return parser


def _one_line(text: object) -> str:
    """An error message on one line (a file name may hold a newline)."""
    return " ".join(str(text).splitlines())


@contextlib.contextmanager
def _termination_unwinds() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise ``Terminated`` (main thread only)."""
    installer = os.getpid()

    def terminate(signum: int, frame: object) -> None:
        if os.getpid() != installer:  # a forked worker (multiprocessing): end as by default
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        raise Terminated(signal.Signals(signum).name)

    with signal_handlers(dict.fromkeys((signal.SIGTERM, signal.SIGHUP), terminate)):
        yield


def _say_compiling(line: str) -> None:
    """The one line of a cold numba compile, on standard error whatever it is (a terminal, a
    notebook's cell, a log file): unlike a progress bar it is written once and says why a first
    run is slow where nobody watches a terminal either."""
    with contextlib.suppress(AttributeError, ValueError, OSError):
        print(f"pendsim: {line}", file=sys.stderr, flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``pendsim`` console script; returns the exit code."""
    compile_notice.set_notice(_say_compiling)
    parser: Parser | None = None
    args: argparse.Namespace | None = None
    try:
        with _termination_unwinds(), replace_hint_as("--force"):
            with interrupts_deferred():  # Ctrl-C while the commands' modules import: acted on after
                parser = build_parser()
            args = parser.parse_args(argv)
            if args.command is None:
                parser.print_help()
                return EXIT_USAGE
            code: int = args.handler(args)
            return code
    except (UsageError, PendsimError) as exc:
        message = _one_line(exc)
        if isinstance(exc, (ParameterError, UsageError)):  # where its values came from, or the option meant
            message = explained(message, args, _command_parser(parser, args))
        print(f"pendsim: error: {message}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as exc:
        if exc.filename is None or isinstance(exc, BrokenPipeError):  # standard output, perhaps: see _run
            raise
        print(
            f"pendsim: error: {_one_line(repr(os.fsdecode(exc.filename)))}: {describe_os_error(exc)}", file=sys.stderr
        )
        return EXIT_USAGE
    except KeyboardInterrupt as exc:  # a command may say what it kept (``str(exc)``: a sweep's saved cases)
        print(f"pendsim: interrupted{': ' + str(exc) if str(exc) else ''}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Terminated as exc:
        print(f"pendsim: stopped by {exc}", file=sys.stderr)
        return EXIT_TERMINATED


def _command_parser(parser: Parser | None, args: argparse.Namespace | None) -> argparse.ArgumentParser | None:
    """The parser of the command that ran (None before one was chosen)."""
    command = getattr(args, "command", None)
    for action in parser._actions if parser is not None and command is not None else ():
        if isinstance(action, argparse._SubParsersAction):
            found: argparse.ArgumentParser | None = action.choices.get(str(command))
            return found
    return None


def _run() -> None:  # pragma: no cover - console script wrapper
    heap.keep_small_blocks()
    heap.collect_rarely()
    for stream in (sys.stdout, sys.stderr):  # a file name that is not UTF-8 prints escaped, never fails
        with contextlib.suppress(AttributeError, ValueError):
            stream.reconfigure(errors="backslashreplace")  # type: ignore[union-attr]
    try:
        code = main()
        sys.stdout.flush()
    except BrokenPipeError:  # the reader went away (pendsim ... | head): stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        code = 0
    except OSError as exc:  # no file named: standard output itself failed (a full disk, ...)?
        try:
            sys.stdout.flush()
            blamed = exc.strerror or str(exc)  # it writes: the error came from elsewhere
        except OSError as again:
            blamed = f"cannot write to standard output: {again.strerror}"
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        print(f"pendsim: error: {blamed}", file=sys.stderr)
        code = EXIT_USAGE
    heap.skip_exit_collection()  # everything is written and published: nothing left to collect for
    sys.exit(code)


if __name__ == "__main__":  # pragma: no cover
    _run()
