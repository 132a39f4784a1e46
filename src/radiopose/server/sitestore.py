"""The site in the database: import a directory, rebuild a :class:`~radiopose.site.Site`.

The database holds the site as *parts*: the text of ``site.toml`` and
``survey.csv``, receiver and device rows, and each pattern's CSV text. A
:class:`~radiopose.site.Site` is always built the one validated way —
the parts are written to a temporary directory in the contract layout and
read back with :func:`radiopose.site.load_site`. An admin edit is therefore
validated exactly like a site on disk: the edited parts must load, or the
edit is rejected whole with load_site's one-line reason and the stored site
stays as it was. :func:`export_site` writes the same directory for
``radiopose locate``.
"""

from __future__ import annotations

import copy
import hashlib
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from radiopose.errors import InputError
from radiopose.site import Site
from radiopose.site_io import load_site
from radiopose.tables import write_table

RECEIVER_FIELDS = ("x_m", "y_m", "z_m", "azimuth_deg", "pitch_deg", "roll_deg")


def read_site_parts(directory: str | os.PathLike[str]) -> tuple[dict[str, Any], str]:
    """Validate a site directory and return its parts and a content hash.

    Raises
    ------
    InputError
        The directory is not a valid site (load_site's message).
    """
    site = load_site(directory)
    root = Path(directory)
    patterns = {
        name: (root / "patterns" / f"{name}.csv").read_text("utf-8") for name in site.patterns
    }
    parts = {
        "files": {
            "site.toml": (root / "site.toml").read_text("utf-8"),
            "survey.csv": (root / "survey.csv").read_text("utf-8"),
        },
        "receivers": [
            {
                "receiver_id": r.receiver_id,
                **{f: float(getattr(r, f)) for f in RECEIVER_FIELDS},
                "pattern": r.pattern,
            }
            for r in site.receivers
        ],
        "devices": [
            {"transmitter": d.transmitter, "pattern": d.pattern, "tx_power_dbm": d.tx_power_dbm}
            for d in site.devices
        ],
        "patterns": patterns,
        "order": ",".join(site.receiver_ids),
    }
    return parts, parts_hash(parts)


def parts_hash(parts: dict[str, Any]) -> str:
    """SHA-256 of the parts' canonical form."""
    h = hashlib.sha256()
    for name in sorted(parts["files"]):
        h.update(f"file {name}\n{parts['files'][name]}\n".encode())
    for r in _ordered_receivers(parts):
        h.update(repr(sorted(r.items())).encode())
    for d in sorted(parts["devices"], key=lambda d: d["transmitter"]):
        h.update(repr(sorted(d.items())).encode())
    for name in sorted(parts["patterns"]):
        h.update(f"pattern {name}\n{parts['patterns'][name]}\n".encode())
    return h.hexdigest()


def _ordered_receivers(parts: dict[str, Any]) -> list[dict[str, Any]]:
    """Receivers in the site's order (the order of receivers.csv; new ones last)."""
    order = [r for r in parts.get("order", "").split(",") if r]
    rank = {r: i for i, r in enumerate(order)}
    return sorted(
        parts["receivers"], key=lambda r: (rank.get(r["receiver_id"], len(rank)), r["receiver_id"])
    )


def write_site_parts(parts: dict[str, Any], directory: str | os.PathLike[str]) -> Path:
    """Write parts as a site directory (contract layout); return its path."""
    root = Path(directory)
    (root / "patterns").mkdir(parents=True, exist_ok=True)
    for name, txt in parts["files"].items():
        (root / name).write_text(txt, encoding="utf-8")
    rx = _ordered_receivers(parts)
    write_table(
        root / "receivers.csv",
        {
            "receiver_id": [r["receiver_id"] for r in rx],
            **{f: np.array([r[f] for r in rx], float) for f in RECEIVER_FIELDS},
            "pattern": [r["pattern"] for r in rx],
        },
        decimals=dict.fromkeys(RECEIVER_FIELDS, 9),
    )
    dev = parts["devices"]
    write_table(
        root / "devices.csv",
        {
            "transmitter": [d["transmitter"] for d in dev],
            "pattern": [d["pattern"] for d in dev],
            "tx_power_dbm": np.array([d["tx_power_dbm"] for d in dev], float),
        },
        decimals={"tx_power_dbm": 9},
    )
    for name, csv in parts["patterns"].items():
        if not _safe_name(name):
            raise InputError(f"pattern name {name!r} is not a plain file name")
        (root / "patterns" / f"{name}.csv").write_text(csv, encoding="utf-8")
    return root


def _safe_name(name: str) -> bool:
    return bool(name) and "/" not in name and "\\" not in name and name not in (".", "..")


def build_site(parts: dict[str, Any]) -> Site:
    """Validate parts and build the site (via a temporary directory and load_site).

    Raises
    ------
    InputError
        The parts do not form a valid site; the message names the file and
        line as load_site saw them (paths relative to the site directory).
    """
    if not parts["files"] or not parts["receivers"]:
        raise InputError("the database holds no site yet (start the server with a SITE)")
    with tempfile.TemporaryDirectory(prefix="radiopose-site-") as tmp:
        write_site_parts(parts, tmp)
        try:
            site = load_site(tmp)
        except InputError as exc:
            raise _relative_to(exc, tmp) from None
    return site


def _relative_to(exc: InputError, tmp: str) -> InputError:
    """``exc`` with the temporary directory ``tmp`` left out of its paths (the
    message names files as they sit in the site: ``patterns/rx1.csv:3``)."""
    return InputError(str(exc).replace(tmp + os.sep, "").replace(tmp, "site"))


def check_pattern_csv(name: str, csv_text: str) -> None:
    """Validate one pattern's CSV text as ``patterns/<name>.csv`` would load, whether
    or not the site uses it yet (:func:`build_site` reads only the patterns in use).

    Raises
    ------
    InputError
        The text is not a pattern CSV; the message names ``patterns/<name>.csv``,
        line and column.
    """
    from radiopose.patterns import read_pattern_csv

    if not _safe_name(name):
        raise InputError(f"pattern name {name!r} is not a plain file name")
    with tempfile.TemporaryDirectory(prefix="radiopose-pattern-") as tmp:
        path = Path(tmp) / "patterns" / f"{name}.csv"
        path.parent.mkdir()
        path.write_text(csv_text, encoding="utf-8")
        try:
            read_pattern_csv(path, name)
        except InputError as exc:
            raise _relative_to(exc, tmp) from None


def export_site(parts: dict[str, Any], directory: str | os.PathLike[str]) -> Path:
    """Write the stored site as a directory that ``radiopose locate`` reads."""
    build_site(parts)
    return write_site_parts(parts, directory)


def edited(parts: dict[str, Any], **changes: Any) -> dict[str, Any]:
    """A deep copy of ``parts`` with top-level keys replaced."""
    out = copy.deepcopy(parts)
    out.update(changes)
    return out
