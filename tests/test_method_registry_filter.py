"""Pinned outputs of ``filter`` through ``locate`` (offline lag 1 s, causal, lag 0.25 s).

Unlike the paper's methods' pins (``test_method_registry.py``), these are
expected to change when the filter itself changes (its accuracy or speed work):
then regenerate them, after checking the accuracy table, with

    PYTHONPATH=src python3 -c "import sys; sys.path.insert(0, 'tests'); \
import pin_support as p; p.write_pins(p.FILTER_PINS, 'pin_filter')"

A refactor of the tracker's plumbing alone must leave them unchanged.
"""

from __future__ import annotations

import pytest

from pin_support import FILTER_PINS, assert_same, read_pins

ROWS, SUMMARY = read_pins("pin_filter")


@pytest.mark.parametrize("pin", FILTER_PINS, ids=lambda p: p.name)
def test_filter_outputs_pinned(pin):
    assert pin.name in SUMMARY
    assert_same(pin, ROWS.get(pin.name, []), SUMMARY[pin.name])
