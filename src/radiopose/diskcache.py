"""An on-disk memo of pure array functions whose cost is scipy's import (start-up speed only).

Loading a site interpolates the survey onto the candidate grid
(``scipy.interpolate``) and checks the survey's convex hull (``scipy.spatial``);
importing those two packages costs ≈ 0.45 CPU-seconds, a tenth of a whole
``radiopose locate`` over 2,000 packets, while the work itself takes a few
milliseconds. :func:`memo_arrays` keeps such results on disk, keyed by a
SHA-256 of every input (dtype, shape and bytes of each array), the function's
name, the source file of the module that computes it (so an edit of the
computation is never answered from an old entry), this module's format
version and the numpy and scipy versions, so a
second load of the same site reads back the identical float64 arrays without
importing scipy (docs/performance.md, "Start-up").

Where: ``$RADIOPOSE_CACHE_DIR`` if set (an empty value turns the cache off),
else ``$XDG_CACHE_HOME/radiopose`` (``~/.cache/radiopose``). One ``.npz`` file
per distinct input (≈ 1.3 MB for the standard site's survey map); delete the
directory to reclaim the space. A file that cannot be read or written is
ignored (the result is computed), so a read-only home or a damaged entry only
costs the time it would have saved.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
import zipfile
import zlib
from collections.abc import Callable, Iterable
from functools import lru_cache
from importlib import metadata
from pathlib import Path

import numpy as np

_FORMAT = "1"
"""Bumped whenever what a namespace's function computes changes."""


def cache_dir() -> Path | None:
    """The cache directory, or ``None`` when ``RADIOPOSE_CACHE_DIR`` is set empty."""
    explicit = os.environ.get("RADIOPOSE_CACHE_DIR")
    if explicit is not None:
        return Path(explicit) if explicit.strip() else None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "radiopose"


@lru_cache(maxsize=1)
def _versions() -> str:
    try:
        scipy_version = metadata.version("scipy")
    except metadata.PackageNotFoundError:  # pragma: no cover - scipy is a dependency
        scipy_version = "none"
    return f"numpy {np.__version__}; scipy {scipy_version}; format {_FORMAT}"


@lru_cache(maxsize=16)
def _source_digest(module: str) -> str:
    """SHA-256 of the source file of ``module`` (empty if it has none)."""
    path = getattr(sys.modules.get(module), "__file__", None)
    if not path:
        return ""
    try:
        with open(path, "rb") as f:
            return hashlib.sha256(f.read()).hexdigest()
    except OSError:
        return ""


def cache_key(namespace: str, parts: Iterable[object], module: str = "") -> str:
    """SHA-256 (hex) of ``namespace``, the library versions, the source of ``module``
    and ``parts`` (arrays by dtype, shape and bytes; anything else by its ``repr``)."""
    h = hashlib.sha256(f"{namespace}\0{_versions()}\0{_source_digest(module)}\0".encode())
    for p in parts:
        if isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(f"array {a.dtype.str} {a.shape}\0".encode())
            h.update(a.tobytes())
        else:
            h.update(f"value {p!r}\0".encode())
    return h.hexdigest()


def memo_arrays(
    namespace: str,
    parts: Iterable[object],
    compute: Callable[[], dict[str, np.ndarray]],
) -> dict[str, np.ndarray]:
    """``compute()`` (named arrays, a pure function of ``parts``), read back from the
    cache when an earlier call with equal ``parts`` stored it.

    Parameters
    ----------
    namespace
        Names the function (part of the key and of the file name).
    parts
        Every input of ``compute``: arrays and plain values.
    compute
        Returns the result as ``{name: array}`` (numeric arrays only); the
        source file of the module defining it is part of the key.

    Returns
    -------
    The arrays, bit for bit what ``compute`` returned for these inputs.
    """
    where = cache_dir()
    if where is None:
        return compute()
    key = cache_key(namespace, parts, getattr(compute, "__module__", "") or "")
    path = where / f"{namespace}-{key}.npz"
    try:
        # the file opened here, not by np.load: a damaged zip leaves np.load's own handle open
        with open(path, "rb") as f, np.load(f, allow_pickle=False) as z:
            return {name: z[name] for name in z.files}
    except (OSError, ValueError, TypeError, KeyError, EOFError, zipfile.BadZipFile, zlib.error):
        # absent or damaged: compute it
        pass
    out = compute()
    try:
        where.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=where, prefix=f".{namespace}-", suffix=".npz")
        try:
            with os.fdopen(fd, "wb") as out_file:
                np.savez(out_file, **out)  # type: ignore[arg-type]  # (numpy stubs: allow_pickle)
            os.replace(tmp, path)  # atomic: a concurrent reader sees all or nothing
        except BaseException:
            os.unlink(tmp)
            raise
    except OSError:  # read-only or full: run without the cache
        pass
    return out
