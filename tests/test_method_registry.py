"""The paper's five methods give exactly the outputs they gave before the tracker
became a package with a method registry (issue 15).

The pins (``tests/data/pin_paper_methods.csv`` and ``.summary.txt``) were written
from the code before the refactor and must never need regenerating: the paper's
methods are the reproduction. (They were written with
``PYTHONPATH=src python3 -c "import sys; sys.path.insert(0, 'tests'); import pin_support as p;
p.write_pins(p.PAPER_PINS, 'pin_paper_methods')"``.)
"""

from __future__ import annotations

import pytest

from pin_support import PAPER_PINS, assert_same, read_pins

ROWS, SUMMARY = read_pins("pin_paper_methods")


@pytest.mark.parametrize("pin", PAPER_PINS, ids=lambda p: p.name)
def test_paper_method_outputs_unchanged(pin):
    assert pin.name in SUMMARY
    assert_same(pin, ROWS.get(pin.name, []), SUMMARY[pin.name])
