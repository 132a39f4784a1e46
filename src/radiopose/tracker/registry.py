"""The one registry of tracking methods: name → :class:`~radiopose.tracker.protocol.Method`.

``radiopose locate --method``, the ``Tracker``/``locate`` API, the live server
(``LiveConfig.method`` and its checkpoints), ``radiopose evaluate``, the demo
and the real-data experiment all read :data:`METHODS`; a method's properties
(evidence, whether it estimates orientation, acquires, lags) come from its
object, never from its name. :func:`register_method` adds one
(``docs/methods.md``); :func:`load_plugins` registers the methods of other
packages (entry points of :data:`PLUGIN_GROUP`) and of the modules named in
:data:`PLUGINS_ENV`, so that every process — the command line, the live
server's pipeline child, ``evaluate``'s Dask workers, the live demo's server —
has them once it imports :mod:`radiopose.tracker`.
"""

from __future__ import annotations

import importlib
import os
import sys
from importlib.metadata import entry_points
from types import ModuleType
from typing import TYPE_CHECKING

from radiopose.errors import InputError
from radiopose.ids import MAX_METHOD_NAME_CHARS
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
    if name not in METHODS:
        # a plugin deferred because its module was still importing when the registry
        # was (the plugin imported first; docs/methods.md) is registered now
        load_plugins()
    try:
        return METHODS[name]
    except KeyError:
        raise InputError(f"unknown method {name!r} (known: {', '.join(METHODS)})") from None


RESERVED_NAMES = frozenset({"textbook"})
"""Names no method may be registered under: ``textbook`` is ``radiopose
evaluate``'s anchor (issue 15's textbook particle filter,
:data:`radiopose.evaluate.textbook_pf.NAME`), which an experiment names in its
``methods`` and which ``evaluate`` registers for a run's duration itself."""

PLUGIN_GROUP = "radiopose.methods"
"""Entry-point group of the methods of other packages. Each entry's value is
``module:object`` (a :class:`Method`, registered under its own name) or
``module`` (imported; it registers its methods itself)."""

PLUGINS_ENV = "RADIOPOSE_METHODS"
"""Environment variable naming modules with methods, comma-separated, each
``module`` or ``module:object`` as in :data:`PLUGIN_GROUP` (for a method not
installed as a package: the module must be importable, e.g. on
``PYTHONPATH``; child processes inherit the variable)."""

_LOADED: dict[str, tuple[str, ...]] = {}
"""Plugin specs loaded in this process → the names each registered."""


def register_method(method: Method, *, replace: bool = False) -> None:
    """Add ``method`` to :data:`METHODS` (``replace`` to override a name).

    A name is a lower-case word (letters, digits, ``-``, ``_``) of at most
    :data:`~radiopose.ids.MAX_METHOD_NAME_CHARS` characters, not one of
    :data:`RESERVED_NAMES`. The live server checkpoints each device's state by
    pickling it, so a method's states must pickle (docs/methods.md).

    Raises
    ------
    ValueError
        The object does not follow the protocol, its name is not such a word
        or is reserved, or the name is taken.
    """
    if not isinstance(method, Method):
        raise ValueError(f"{method!r} does not follow the Method protocol")
    name = method.name
    if not (
        isinstance(name, str)
        and name
        and name == name.lower()
        and name.replace("-", "").replace("_", "").isalnum()
        and name.isascii()
    ):
        raise ValueError(f"method name {name!r} must be a lower-case word")
    if len(name) > MAX_METHOD_NAME_CHARS:
        raise ValueError(
            f"method name {name!r} has {len(name)} characters; at most "
            f"{MAX_METHOD_NAME_CHARS} (the live server's database stores it)"
        )
    if name in RESERVED_NAMES:
        raise ValueError(f"method name {name!r} is reserved (radiopose evaluate's anchor)")
    if name in METHODS and not replace:
        raise ValueError(f"method {name!r} is already registered")
    METHODS[name] = method


def load_plugins() -> tuple[str, ...]:
    """Register the methods of other packages and modules: every entry point
    of :data:`PLUGIN_GROUP`, then each module of :data:`PLUGINS_ENV`, in that
    order. Each spec is loaded once per process (a later call loads only what
    is new, e.g. after the variable changed).

    Returns
    -------
    The names the plugins loaded so far registered, in their order.

    Raises
    ------
    InputError
        A plugin cannot be imported or its object is not a method, or its
        method cannot be registered (one line naming the entry point or the
        variable, and why).
    """
    specs = [
        (f"entry point {ep.name!r} of {PLUGIN_GROUP} ({ep.value})", ep.value)
        for ep in entry_points(group=PLUGIN_GROUP)
    ]
    env = os.environ.get(PLUGINS_ENV, "")
    specs += [(f"{PLUGINS_ENV} entry {v!r}", v) for v in (x.strip() for x in env.split(",")) if v]
    for where, spec in specs:
        if spec in _LOADED:
            continue
        before = set(METHODS)
        _LOADED[spec] = ()  # (a plugin importing radiopose.tracker again does not recurse)
        try:
            loaded = _load_spec(where, spec)
        except BaseException:
            del _LOADED[spec]  # not loaded: a later call tries again, from scratch
            for name in [n for n in METHODS if n not in before]:
                del METHODS[name]  # (what the failed plugin registered before failing)
            raise
        if not loaded:  # its module is still importing: a later call loads it
            del _LOADED[spec]
            continue
        _LOADED[spec] = tuple(n for n in METHODS if n not in before)
    return tuple(n for names in _LOADED.values() for n in names)


def plugin_sources() -> dict[str, str]:
    """The methods plugins registered in this process → the spec that did
    (``module`` or ``module:object``, from an entry point or
    :data:`PLUGINS_ENV`)."""
    return {name: spec for spec, names in _LOADED.items() for name in names}


def _load_spec(where: str, spec: str) -> bool:
    """Import ``module`` or ``module:object`` and register the object; ``False``
    (nothing done) while that module is itself still being imported — it
    imported :mod:`radiopose.tracker` first, whose import is loading the
    plugins now: :func:`get_method` loads it once it is complete."""
    module, _, attr = spec.partition(":")
    partial = sys.modules.get(module.strip())
    if partial is not None and getattr(getattr(partial, "__spec__", None), "_initializing", False):
        return False
    try:
        obj: object = importlib.import_module(module.strip())
        for part in attr.strip().split(".") if attr.strip() else ():
            obj = getattr(obj, part)
        if isinstance(obj, ModuleType):
            return True  # the module registered its methods on import
        if isinstance(obj, type):
            raise ValueError(f"{obj.__name__} is a class, not a method object (an instance)")
        if not isinstance(obj, Method):
            raise ValueError(f"{obj!r} does not follow the Method protocol")
        if METHODS.get(obj.name) is not obj:
            register_method(obj)
        return True
    except InputError:
        raise
    except Exception as exc:  # a plugin's own failure, reported as one line
        why = (str(exc).strip().splitlines() or [""])[0]
        raise InputError(f"{where}: {type(exc).__name__}: {why}"[:400]) from exc
