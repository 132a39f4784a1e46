"""Identifier rules shared by every reader (kept free of heavy imports).

A transmitter id is any string without commas or whitespace (the contract,
``formats.md``): a MAC address for real devices, a name such as ``phone`` in
simulations.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from radiopose.tables import Table

MAX_TRANSMITTER_ID_CHARS = 64

MAX_METHOD_NAME_CHARS = 16
"""The longest tracking method name (the live server's database stores it with
each estimate in a column of this width)."""


def transmitter_id_problem(value: str) -> str | None:
    """Why ``value`` is not a transmitter id, or ``None`` if it is one.

    The contract: any string without commas or whitespace (a MAC address for
    real devices, a name such as ``phone`` in simulations); here also printable
    and 1–64 characters.
    """
    if not 0 < len(value) <= MAX_TRANSMITTER_ID_CHARS:
        return f"a transmitter id has 1-{MAX_TRANSMITTER_ID_CHARS} characters, got {len(value)}"
    if "," in value or any(c.isspace() for c in value) or not value.isprintable():
        return f"not a transmitter id (no commas, whitespace or control characters): {value[:40]!r}"
    return None


def check_transmitter_ids(table: Table, column: str = "transmitter") -> None:
    """Raise at the first row of ``table`` whose ``column`` is not a transmitter
    id (:func:`transmitter_id_problem`), naming its file, line and column.

    Each distinct value is checked once, so a large file costs one pass over
    its distinct ids.
    """
    import numpy as np

    values = np.asarray(table[column]).astype(str)
    if values.size == 0:
        return
    distinct, first = np.unique(values, return_index=True)
    bad = [
        (row, problem)
        for value, row in zip(distinct.tolist(), first.tolist(), strict=True)
        if (problem := transmitter_id_problem(value)) is not None
    ]
    if bad:
        row, problem = min(bad)
        raise table.error(row, column, problem)
