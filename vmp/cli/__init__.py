"""The ``vmp`` command: one small module per subcommand over the library's functions."""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Sequence

from vmp.cli.interrupt import handled_interrupt
from vmp.cli.parser import build_parser
from vmp.errors import InputError

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``vmp ARGV``; returns the exit code (2: a user's mistake, 128 + N: signal N)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    previous = _terminate_as_interrupt()
    try:
        code = int(args.run(args))
        sys.stdout.flush()  # here, where a reader gone away is told apart (below)
        return code
    except InputError as exc:
        print(f"vmp {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # The reader of the output went away ('vmp evaluate ... | head -1'): as a Unix tool
        # does, stop without a word. Standard output is pointed at nothing, so that Python's
        # flush at exit does not fail on it again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + signal.SIGPIPE.value
    except OSError as exc:
        name = f": {exc.filename}" if getattr(exc, "filename", None) else ""
        print(f"vmp {args.command}: error: {exc.strerror or exc}{name}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        handled_interrupt()
        print(f"vmp {args.command}: interrupted", file=sys.stderr)
        return 130
    except _Terminated:
        print(f"vmp {args.command}: terminated (SIGTERM); nothing half-written is left",
              file=sys.stderr)
        return 128 + signal.SIGTERM.value
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


class _Terminated(BaseException):
    """SIGTERM in a command that has no way of its own to end early."""


def _terminate_as_interrupt():
    """Make SIGTERM end any command the way Ctrl-C does (files are written atomically, so
    nothing half-written is left); commands that finish their work on a signal (map, live,
    localize, simulate) install their own handler over this one. Returns the handler before."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def handler(_signum: int, _frame: object) -> None:
        raise _Terminated

    return signal.signal(signal.SIGTERM, handler)
