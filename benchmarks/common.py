"""What every benchmark reports beside its numbers: the machine, and tables.

Speed is reported as ratios against a baseline measured in the same run; the
machine line (versions, threads, cores, the 1-minute load average when the run
started) says how far absolute numbers can be trusted.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

import numba
import numpy as np


def machine() -> dict:
    """Python, numpy and numba versions, numba's threads, cores, CPU model, load."""
    info: dict = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "numba_threads": numba.get_num_threads(),
        "cpus": os.cpu_count(),
        "machine": platform.machine(),
    }
    try:
        with open("/proc/cpuinfo") as fh:
            info["cpu"] = next(
                (ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), "?"
            )
    except OSError:
        pass
    info["load_average_1m"] = round(os.getloadavg()[0], 2)
    return info


def table(rows: list[dict], fmt: dict[str, str]) -> list[str]:
    """A Markdown table of ``rows`` (keys of the first row as columns; floats
    formatted by ``fmt[key]``), followed by an empty line."""
    keys = list(rows[0])
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        cells = [
            format(r[k], fmt.get(k, "")) if isinstance(r[k], float) else str(r[k]) for k in keys
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return [*lines, ""]


def emit(lines: list[str], markdown: str | None) -> int:
    """Print the report and, if ``markdown`` names a file, write it there too
    (its missing parent directories made, as ``scripting.check_output``, which
    the benchmarks run before their work, allows); 0."""
    text = "\n".join(lines)
    print(text)
    if markdown:
        path = Path(markdown)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text + "\n", encoding="utf-8")
    return 0
