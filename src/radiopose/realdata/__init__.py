"""Real data: the public BLE tracking site ("tetam") imported, localised and scored.

* :mod:`radiopose.realdata.tetam` — the dataset's files, parsed and validated;
  readings grouped into advertisements (packets), orientation matrices read.
* :mod:`radiopose.realdata.build` — the site and tracks in the interchange
  format (``radiopose import tetam``), with a held-out site per track.
* :mod:`radiopose.realdata.experiment` — every track localised with nothing
  learnt from itself, scored beside anchors (``scripts/real_data.py``).
* :mod:`radiopose.realdata.demo` — ``radiopose demo --real``.

docs/real-data.md has the decisions and the numbers.
"""
