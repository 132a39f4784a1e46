"""Why a packet has no estimate: the skip reasons the tracker counts (one string each)."""

from __future__ import annotations

SKIP_UNKNOWN_TRANSMITTER = "unknown transmitter"
SKIP_TOO_FEW_RECEIVERS = "too few receivers"
SKIP_OUT_OF_ORDER = "timestamp before previous packet"
SKIP_NO_CANDIDATES = "no scorable candidate"
SKIP_NO_ORIENTATION_CLUSTER = "no orientation cluster"
SKIP_ROTATION_MODEL = "rejected by rotation model"
SKIP_NO_POSITION_CLUSTER = "no position cluster"
SKIP_MOVEMENT_MODEL = "rejected by movement model"
SKIP_ACQUIRING = "acquiring (pooling packets)"
SKIP_NO_TRACK = "no track yet (acquiring: too few receivers or nothing scorable)"
SKIP_DUPLICATE = "duplicate packet (given twice)"
SKIP_SITE_CHANGED = "site changed before its estimate"
"""The live server: the packet's estimate was held back (a lag) by an engine
that a site edit replaced, and a crash lost the site it was derived under."""
SKIP_ENGINE_UNRECORDED = "held back by an engine the checkpoint did not record"
"""The live server: the packet's estimate was held back (a lag) by the engine of a
checkpoint written before engines were recorded (``PipelineState.method``, an
older version), and a restart with another method cannot hand it over."""
SKIP_METHOD_FAILED = "the method failed (the device starts afresh)"
"""The live server: the method raised on this packet (or gave an estimate the
contract does not allow); the error is logged, and the device's state and its
estimates still held back are dropped, so that the other devices go on."""
PENDING = "pending (smoothing lag)"
"""Not a skip: the method will emit this packet's estimate later (fixed-lag smoother)."""
