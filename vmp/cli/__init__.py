"""The ``vmp`` command: one small module per subcommand over the library's functions."""

from __future__ import annotations

import sys
from collections.abc import Sequence

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
    try:
        return int(args.run(args))
    except InputError as exc:
        print(f"vmp {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        name = f": {exc.filename}" if getattr(exc, "filename", None) else ""
        print(f"vmp {args.command}: error: {exc.strerror or exc}{name}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"vmp {args.command}: interrupted", file=sys.stderr)
        return 130
