"""Reproduce the shipped real-phone patterns from the MIT LL chamber captures.

Usage::

    python scripts/enrol_mitll.py [--data ../shared/data/phone-patterns-mitll]
        [--patterns-dir src/radiopose/data/patterns] [--figures-dir docs/img]

Writes ``src/radiopose/data/patterns/{iphone-11,galaxy-s10}.csv``,
``docs/img/pattern-{iphone-11,galaxy-s10}.png`` and the overlay
``docs/img/pattern-phones.png``, and prints each directivity range.
Method: :func:`radiopose.patterns.importers.read_mitll` with the default
:class:`~radiopose.patterns.enrol.EnrolConfig` (``docs/patterns.md``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt

from radiopose.patterns.importers import read_mitll
from radiopose.patterns.pattern import write_pattern_csv
from radiopose.patterns.plot import plot_polar, save_pattern_figure
from radiopose.scripting import check_output, run_script

ROOT = Path(__file__).resolve().parents[1]
PATTERNS_DIR = ROOT / "src" / "radiopose" / "data" / "patterns"
FIGURES_DIR = ROOT / "docs" / "img"
PHONES = {"iphone-11": "iPhone-11-2", "galaxy-s10": "Samsung-Galaxy-S10-2"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--data", type=Path, default=ROOT.parent / "shared" / "data" / "phone-patterns-mitll"
    )
    parser.add_argument("--patterns-dir", type=Path, default=PATTERNS_DIR)
    parser.add_argument("--figures-dir", type=Path, default=FIGURES_DIR)
    args = parser.parse_args(argv)
    if not args.data.is_dir():  # checked before anything is read or written
        parser.error(f"--data {args.data}: no such directory (the MIT LL chamber captures)")
    for folder in PHONES.values():
        if not (args.data / folder).is_dir():
            parser.error(f"--data {args.data}: no {folder}/ in it (the MIT LL chamber captures)")
    check_output(parser, "--patterns-dir", dirs=[args.patterns_dir])
    check_output(parser, "--figures-dir", dirs=[args.figures_dir])
    check_output(parser, "--patterns-dir", files=[args.patterns_dir / f"{n}.csv" for n in PHONES])
    figures = [args.figures_dir / f"pattern-{n}.png" for n in [*PHONES, "phones"]]
    check_output(parser, "--figures-dir", files=figures)
    # every phone read before anything is written: a bad capture leaves no output
    patterns = {name: read_mitll(args.data / folder, name=name) for name, folder in PHONES.items()}
    fig = plt.figure(figsize=(5.5, 5.5))
    ax = fig.add_subplot(projection="polar")
    for name, pattern in patterns.items():
        write_pattern_csv(pattern, args.patterns_dir / f"{name}.csv")
        save_pattern_figure(pattern, args.figures_dir / f"pattern-{name}.png")
        lo, hi = pattern.range_dbi
        print(f"{name}: directivity {lo:+.2f} … {hi:+.2f} dBi (span {hi - lo:.2f} dB)")
        plot_polar(pattern, ax=ax)
    ax.set_title("MIT LL chamber phones, 90° slice, directivity dBi", fontsize=10)
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    fig.savefig(args.figures_dir / "pattern-phones.png", dpi=120)
    plt.close(fig)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
