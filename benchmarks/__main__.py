"""Runs one benchmark: ``python -m benchmarks [BENCHMARK] [ARGS...]``.

BENCHMARK is one of likelihood, capture, server, filter, pose3d, prune,
profile, devices and sharing.

Default ``likelihood`` (kernel, pipeline, scaling, memory and start-up tables;
see ``docs/performance.md``). The remaining arguments go to that benchmark,
e.g. ``python -m benchmarks likelihood --quick --markdown out.md`` or
``python -m benchmarks capture --help``. ``python -m benchmarks --help`` lists
the benchmarks.
"""

from __future__ import annotations

import ast
import runpy
import sys
from pathlib import Path

NAMES = (
    "likelihood",
    "capture",
    "server",
    "filter",
    "pose3d",
    "prune",
    "profile",
    "devices",
    "sharing",
)
HERE = Path(__file__).resolve().parent


def summary(name: str) -> str:
    """First line of a benchmark's module docstring (read without importing it)."""
    doc = ast.get_docstring(ast.parse((HERE / f"bench_{name}.py").read_text(encoding="utf-8")))
    return (doc or "").strip().splitlines()[0] if doc else ""


def usage() -> str:
    lines = [
        "usage: python -m benchmarks [BENCHMARK] [ARGS...]",
        "",
        "Runs one benchmark (default: likelihood); ARGS go to it, e.g.",
        "python -m benchmarks capture --help",
        "",
        "benchmarks:",
    ]
    lines += [f"  {name:12s}{summary(name)}" for name in NAMES]
    return "\n".join(lines)


def main() -> None:
    args = sys.argv[1:]
    if args and args[0] in ("-h", "--help"):
        print(usage())
        return
    name = "likelihood"
    if args and args[0] in NAMES:
        name, args = args[0], args[1:]
    elif args and not args[0].startswith("-"):
        sys.exit(f"benchmarks: unknown benchmark {args[0]!r} (choose from {', '.join(NAMES)})")
    path = HERE / f"bench_{name}.py"
    sys.argv = [str(path), *args]
    runpy.run_path(str(path), run_name="__main__")


if __name__ == "__main__":
    main()
