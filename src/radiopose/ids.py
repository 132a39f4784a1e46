"""Identifier rules shared by every reader (kept free of heavy imports).

A transmitter id is any string without commas or whitespace (the contract,
``formats.md``): a MAC address for real devices, a name such as ``phone`` in
simulations. A receiver id follows the same rule (the contract names no rule
for it; one rule everywhere — receivers.csv, survey.csv, packets.csv, CSV
captures, ``sync --receiver ID=FILE``, ``receiver --id``, the API — so that an
id accepted by one reader is accepted by every other).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from radiopose.tables import Table

MAX_TRANSMITTER_ID_CHARS = 64

MAX_METHOD_NAME_CHARS = 16
"""The longest tracking method name (the live server's database stores it with
each estimate in a column of this width)."""


MAX_RECEIVER_ID_CHARS = 64
"""The longest receiver id (the live server's database column width)."""


def _id_problem(value: str, what: str, longest: int) -> str | None:
    if not 0 < len(value) <= longest:
        return f"a {what} has 1-{longest} characters, got {len(value)}"
    if "," in value or any(c.isspace() for c in value) or not value.isprintable():
        return f"not a {what} (no commas, whitespace or control characters): {value[:40]!r}"
    return None


def transmitter_id_problem(value: str) -> str | None:
    """Why ``value`` is not a transmitter id, or ``None`` if it is one.

    The contract: any string without commas or whitespace (a MAC address for
    real devices, a name such as ``phone`` in simulations); here also printable
    and 1–64 characters.
    """
    return _id_problem(value, "transmitter id", MAX_TRANSMITTER_ID_CHARS)


def receiver_id_problem(value: str) -> str | None:
    """Why ``value`` is not a receiver id, or ``None`` if it is one: the rule of
    transmitter ids (no commas or whitespace, printable, 1–64 characters)."""
    return _id_problem(value, "receiver id", MAX_RECEIVER_ID_CHARS)


def check_receiver_ids(table: Table, column: str = "receiver_id") -> None:
    """:func:`check_transmitter_ids` for receiver ids (:func:`receiver_id_problem`)."""
    _check_ids(table, column, receiver_id_problem)


def check_transmitter_ids(table: Table, column: str = "transmitter") -> None:
    """Raise at the first row of ``table`` whose ``column`` is not a transmitter
    id (:func:`transmitter_id_problem`), naming its file, line and column.

    Each distinct value is checked once, so a large file costs one pass over
    its distinct ids.
    """
    _check_ids(table, column, transmitter_id_problem)


def _check_ids(table: Table, column: str, problem_of: Callable[[str], str | None]) -> None:
    import numpy as np

    values = np.asarray(table[column]).astype(str)
    if values.size == 0:
        return
    distinct, first = np.unique(values, return_index=True)
    bad = [
        (row, problem)
        for value, row in zip(distinct.tolist(), first.tolist(), strict=True)
        if (problem := problem_of(value)) is not None
    ]
    if bad:
        row, problem = min(bad)
        raise table.error(row, column, problem)
