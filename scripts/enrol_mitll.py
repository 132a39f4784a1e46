"""Reproduce the shipped real-phone patterns from the MIT LL chamber captures.

Usage::

    python scripts/enrol_mitll.py [--data ../shared/data/phone-patterns-mitll]

Writes ``src/radiopose/data/patterns/{iphone-11,galaxy-s10}.csv`` and
``docs/img/pattern-{iphone-11,galaxy-s10}.png`` and prints each directivity
range. Method: :func:`radiopose.patterns.importers.read_mitll` with the default
:class:`~radiopose.patterns.enrol.EnrolConfig` (``docs/patterns.md``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

from radiopose.patterns.importers import read_mitll  # noqa: E402
from radiopose.patterns.pattern import write_pattern_csv  # noqa: E402
from radiopose.patterns.plot import save_pattern_figure  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PHONES = {"iphone-11": "iPhone-11-2", "galaxy-s10": "Samsung-Galaxy-S10-2"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--data", type=Path, default=ROOT.parent / "shared" / "data" / "phone-patterns-mitll"
    )
    args = parser.parse_args()
    for name, folder in PHONES.items():
        pattern = read_mitll(args.data / folder, name=name)
        write_pattern_csv(pattern, ROOT / "src" / "radiopose" / "data" / "patterns" / f"{name}.csv")
        save_pattern_figure(pattern, ROOT / "docs" / "img" / f"pattern-{name}.png")
        lo, hi = pattern.range_dbi
        print(f"{name}: directivity {lo:+.2f} … {hi:+.2f} dBi (span {hi - lo:.2f} dB)")


if __name__ == "__main__":
    main()
