"""The ``posturemap`` command: parses arguments and calls the library (thin by design)."""

from __future__ import annotations

import argparse
import os
import sys

from . import __version__
from .errors import UserError


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line on stderr and exit code 2 (no usage dump)."""

    def error(self, message):
        sys.stderr.write(f"posturemap: error: {message}\n")
        sys.exit(2)


def _cmd_demo(args) -> int:
    from . import demo
    demo.run(args.out, data=args.data, log=print)
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="posturemap",
                description="Natural, real-time motion transitions between motion-capture clips "
                            "with a Uniform Posture Map.")
    p.add_argument("--version", action="version", version=f"posturemap {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    d = sub.add_parser("demo", help="run the whole pipeline on the bundled sample (or --data DIR)")
    d.add_argument("--out", default="out", help="output folder (default: out)")
    d.add_argument("--data", default=None, help="folder of BVH files to use instead of the sample")
    d.set_defaults(func=_cmd_demo)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return args.func(args)
    except UserError as e:
        sys.stderr.write(f"posturemap: error: {e}\n")
        return 2
    except FileNotFoundError as e:
        sys.stderr.write(f"posturemap: error: {e.filename}: no such file or folder\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("posturemap: interrupted\n")
        return 130


if __name__ == "__main__":  # pragma: no cover
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
