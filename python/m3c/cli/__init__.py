"""The `m3c` command line: main() runs the command the arguments name (parser: m3c.cli.parser; the commands: one
module per group) and turns the errors a user can fix into a message and an exit code."""

from __future__ import annotations

import errno
import sys
from pathlib import Path

from m3c.cli.common import EXIT_INPUT, EXIT_UNAVAILABLE
from m3c.cli.parser import CAMERA_KINDS_TEXT, build_parser

__all__ = ["CAMERA_KINDS_TEXT", "EXIT_INPUT", "EXIT_UNAVAILABLE", "build_parser", "main"]

_USER_OS_ERRORS = {errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.ENOTDIR,
                   errno.EISDIR}


def main(argv: list[str] | None = None) -> int:
    from m3c.pipeline import ComponentUnavailable, PipelineError, PipelineUnavailable

    args = build_parser().parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # the command as given, for benchmark provenance
    try:
        return args.func(args)
    except PipelineUnavailable as err:
        print(f"m3c: error: {err}", file=sys.stderr)
        if getattr(args, "out", None) and Path(args.out).is_dir():
            print(f"m3c: nothing was computed that depends on them; the cache in {args.out} is kept", file=sys.stderr)
        return EXIT_UNAVAILABLE
    except (ComponentUnavailable, ImportError) as err:  # ImportError: an optional backend is not installed
        print(f"m3c: error: {err}", file=sys.stderr)
        return EXIT_UNAVAILABLE
    except (PipelineError, FileNotFoundError, ValueError) as err:
        print(f"m3c: error: {err}", file=sys.stderr)
        return EXIT_INPUT
    except OSError as err:
        if err.errno not in _USER_OS_ERRORS:
            raise
        # The file system refused a write or read the user can fix (permissions, a full or read-only disk).
        print(f"m3c: error: {err}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("m3c: interrupted; finished nodes are cached, run the same command again to resume", file=sys.stderr)
        return 130
