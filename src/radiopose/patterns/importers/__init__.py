"""Importers for industry pattern files and real phone measurements.

Every importer returns a :class:`~radiopose.patterns.pattern.Pattern` in the
contract's pattern coordinates (``docs/patterns.md``): azimuth ``phi``
counter-clockwise about body ``+z`` from body ``+x``, polar angle ``theta``
from body ``+z``. For a base-station antenna file the antenna is mounted in
the body frame with its **boresight along body +x** and its **zenith (up) along
body +z**, so the file's horizontal plane is the pattern's ``theta = 90°``
plane.

* :func:`read_msi` — MSI/Planet ``.msi``/``.pln`` (two 2-D cuts).
* :func:`read_basta_json` — NGMN BASTA 3-D pattern JSON (WP3.0 ``3drp``).
* :func:`read_mitll_measurements` / :func:`read_mitll` — the MIT LL
  PACT anechoic-chamber BLE captures (``btle_sniffer_*.csv``), enrolled with
  :func:`~radiopose.patterns.enrol.enrol`.

Industry files carry *gain* (directivity × efficiency) in dBi; by default the
importers keep it (``directivity_dbi = G − attenuation``) so the absolute link
budget is right. ``normalise=True`` rescales to a directivity in the
radiopose sense (mean intensity 0 dBi over the sphere, or over the slice).

The package holds one module per format (:mod:`.msi`, :mod:`.basta`,
:mod:`.mitll`) over shared checks (:mod:`._common`); a new format goes in a
new module here, re-exported below.
"""

from radiopose.patterns.importers._common import DBD_TO_DBI
from radiopose.patterns.importers.basta import read_basta_json
from radiopose.patterns.importers.mitll import (
    MITLL_CHANNELS,
    read_mitll,
    read_mitll_measurements,
)
from radiopose.patterns.importers.msi import read_msi

__all__ = [
    "DBD_TO_DBI",
    "MITLL_CHANNELS",
    "read_basta_json",
    "read_mitll",
    "read_mitll_measurements",
    "read_msi",
]
