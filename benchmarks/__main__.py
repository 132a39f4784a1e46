"""``python -m benchmarks [likelihood|capture|server] [ARGS...]``: run one benchmark.

Default ``likelihood`` (kernel, pipeline, scaling, memory and start-up tables;
see ``docs/performance.md``). The remaining arguments go to that benchmark,
e.g. ``python -m benchmarks likelihood --quick --markdown out.md``.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

NAMES = ("likelihood", "capture", "server")


def main() -> None:
    args = sys.argv[1:]
    name = "likelihood"
    if args and args[0] in NAMES:
        name, args = args[0], args[1:]
    elif args and not args[0].startswith("-"):
        sys.exit(f"benchmarks: unknown benchmark {args[0]!r} (choose from {', '.join(NAMES)})")
    path = Path(__file__).with_name(f"bench_{name}.py")
    sys.argv = [str(path), *args]
    runpy.run_path(str(path), run_name="__main__")


if __name__ == "__main__":
    main()
