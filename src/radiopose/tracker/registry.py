"""The one registry of tracking methods: name → :class:`~radiopose.tracker.protocol.Method`.

``radiopose locate --method``, the ``Tracker``/``locate`` API, the live server
(``LiveConfig.method`` and its checkpoints), ``radiopose evaluate``, the demo
and the real-data experiment all read :data:`METHODS`; a method's properties
(evidence, whether it estimates orientation, acquires, lags) come from its
object, never from its name. :func:`register_method` adds one
(``docs/methods.md``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from radiopose.errors import InputError
from radiopose.tracker.filter import FILTER
from radiopose.tracker.lms import LMS
from radiopose.tracker.paper import FULL, LOCATION, ORIENTATION, TOP
from radiopose.tracker.protocol import Method

if TYPE_CHECKING:
    from radiopose.site import Site

METHODS: dict[str, Method] = {m.name: m for m in (FULL, LOCATION, ORIENTATION, TOP, LMS, FILTER)}
"""Every method by name: the paper's five and ``filter``, the Bayesian tracker
(:mod:`radiopose.filtering`, docs/filter.md). Iterating gives the names."""

PAPER_METHODS: tuple[str, ...] = ("full", "location", "orientation", "top", "lms")
"""The paper's five comparison methods (the reproduction)."""

METHOD_NAMES: tuple[str, ...] = tuple(METHODS)
"""The built-in methods' names, in registry order (the paper's five, then ``filter``)."""

DEFAULT_LIVE_METHOD = "full"
"""The live server's method at a 2-D site when none is chosen (``radiopose serve
--method``, the site's ``live_method``): issue 15 makes ``filter`` the default
once its live variant meets the issue's goals (docs/methods.md)."""

DEFAULT_LIVE_METHOD_3D = "filter"
"""The live server's method at a 3-D site when none is chosen: the paper's
methods search every candidate per packet, which at a 3-D site is far too slow
for live data (the simulated 3-D site: ``full`` 15–16 packets/s against
629–712 for ``filter``, while the phone sends 200; ``python -m benchmarks
sharing``, docs/methods.md)."""


def default_live_method(site: Site) -> str:
    """The live method when none is chosen: :data:`DEFAULT_LIVE_METHOD_3D` at a
    3-D site (:func:`radiopose.site.site_is_3d`: a height range, several
    pitches or rolls), else :data:`DEFAULT_LIVE_METHOD`."""
    from radiopose.site import site_is_3d

    return DEFAULT_LIVE_METHOD_3D if site_is_3d(site) else DEFAULT_LIVE_METHOD


def get_method(name: str) -> Method:
    """The method registered under ``name``.

    Raises
    ------
    InputError
        No such method (the message lists the known ones).
    """
    try:
        return METHODS[name]
    except KeyError:
        raise InputError(f"unknown method {name!r} (known: {', '.join(METHODS)})") from None


def register_method(method: Method, *, replace: bool = False) -> None:
    """Add ``method`` to :data:`METHODS` (``replace`` to override a name).

    Raises
    ------
    ValueError
        The object does not follow the protocol, its name is not a lower-case
        word, or the name is taken.
    """
    if not isinstance(method, Method):
        raise ValueError(f"{method!r} does not follow the Method protocol")
    name = method.name
    if not (name and name == name.lower() and name.replace("-", "").replace("_", "").isalnum()):
        raise ValueError(f"method name {name!r} must be a lower-case word")
    if name in METHODS and not replace:
        raise ValueError(f"method {name!r} is already registered")
    METHODS[name] = method
