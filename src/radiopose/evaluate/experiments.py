"""Experiments as declarative TOML: a base scenario, a sweep, runs, methods, figures.

An experiment file describes one of the paper's evaluations (or a user's own):

.. code-block:: toml

    name = "noise"                      # also the results' `experiment` column
    title = "Packet RSS noise"
    description = "σ from 0.5 to 3 dB, 4 receivers (paper, Fig. …)"
    seed = 70101                        # every run's seed derives from this
    runs = 10                           # seeded runs per condition
    methods = ["full", "location", "orientation", "top", "lms"]
    kernel = "auto"                     # likelihood scorer; auto = fastest available

    [scenario]                          # ScenarioConfig fields (simulate/scenario.py)
    n_receivers = 4
    duration_s = 2.0

    [motion]                            # MotionConfig fields (simulate/trajectories.py)
    rotation = "linear"

    [tracker]                           # TrackerConfig fields (tracker/config.py), paper defaults
    k = 100

    [sweep]                             # conditions: the Cartesian product, in file order
    scenario.noise_db = [0.5, 1.0, 1.5, 2.0, 2.5, 3.0]

    [quick]                             # overrides for `radiopose evaluate --quick`
    runs = 3
    scenario.duration_s = 0.5
    sweep.scenario.noise_db = [0.5, 1.5, 3.0]

    [[figure]]                          # figures of the report (see FigureSpec)
    kind = "error"                      # error | reduction | relative
    x = "noise_db"
    quantity = "orientation"            # position | orientation

Every key is typed and checked; an unknown key, a wrong type or a value out of
range is one :class:`~radiopose.errors.InputError` naming the file and the
dotted key (``sweep.scenario.noise_db``, ``quick.runs``, ``figure[2].x``).

The paper's five experiments ship as package data (:data:`SHIPPED`, the files in
``radiopose/evaluate/experiments/``) and are loaded by name with :func:`load_experiment`.

The module is one piece (about 660 lines, a quarter of them docstrings and the
example above): the value objects, the typed reading of each table and the
loading share the file's dotted key names and error wording, and no part is
used apart from the others.
"""

from __future__ import annotations

import itertools
import math
import os
import re
import types
import typing
from dataclasses import dataclass, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any, Literal

from radiopose.config import Section, load_toml
from radiopose.errors import InputError
from radiopose.simulate import MotionConfig, ScenarioConfig
from radiopose.tracker import METHOD_NAMES, METHODS, TrackerConfig

SHIPPED: tuple[str, ...] = ("noise", "receivers", "interval", "motion", "bounds")
"""The paper's experiments, in the order of the report."""
SHIPPED_BEYOND: tuple[str, ...] = ("3d", "anchor")
"""Shipped experiments beyond the paper, loaded by name but not run by default
(``3d``: the 3-D hand-held scenario, docs/pose3d.md; ``anchor``: the noise
experiment with issue 15's anchor, :data:`ANCHOR`, beside the methods)."""

FigureKind = Literal["error", "reduction", "relative"]
Quantity = Literal["position", "orientation"]
KERNEL_AUTO = "auto"
MAX_CONDITIONS = 10_000
"""Most conditions a sweep may multiply out to (the shipped experiments have
at most a few dozen); more is an error naming the sweep, not an hour of parsing."""
MAX_TASKS = 1_000_000
"""Most runs of an experiment in all (conditions × runs)."""

# Fields of the configuration dataclasses that an experiment may set, per table.
_SCENARIO_SKIP = {"channel", "motion"}
_TRACKER_SKIP = {"kernel"}
_TABLES: dict[str, tuple[type, set[str]]] = {
    "scenario": (ScenarioConfig, _SCENARIO_SKIP),
    "motion": (MotionConfig, set()),
    "tracker": (TrackerConfig, _TRACKER_SKIP),
}


# ----------------------------------------------------------------------------- values
@dataclass(frozen=True)
class FigureSpec:
    """One figure of the report.

    Attributes
    ----------
    kind
        ``"error"``: mean error over runs with 95 % confidence intervals;
        ``"reduction"``: relative error reduction (%) versus ``baseline``;
        ``"relative"``: error divided by the error at ``x = reference``.
    x
        The swept parameter on the horizontal axis (its short name, e.g. ``noise_db``).
    quantity
        ``"position"`` (metres) or ``"orientation"`` (degrees).
    hue
        ``"method"`` (one line per method) or another swept parameter.
    methods
        Methods drawn (default: every method of the experiment that has the quantity).
    baseline
        Reference method of a reduction (default ``lms`` for position, ``top``
        for orientation).
    reference
        The ``x`` value a ``relative`` figure divides by (default: the first).
    where
        ``(parameter, value)`` pairs fixing the other swept parameters.
    title
        Axes title (default: generated).
    """

    kind: FigureKind
    x: str
    quantity: Quantity
    hue: str = "method"
    methods: tuple[str, ...] | None = None
    baseline: str | None = None
    reference: float | str | None = None
    where: tuple[tuple[str, Any], ...] = ()
    title: str | None = None

    @property
    def baseline_method(self) -> str:
        """The reference method of a reduction."""
        if self.baseline is not None:
            return self.baseline
        return "lms" if self.quantity == "position" else "top"

    @property
    def slug(self) -> str:
        """A file-name friendly identifier."""
        parts = [self.kind, self.quantity, "vs", self.x]
        if self.hue != "method":
            parts += ["by", self.hue]
        parts += [f"{k}-{v}" for k, v in self.where]
        if self.methods and self.hue != "method":
            parts += list(self.methods)
        return re.sub(r"[^A-Za-z0-9_.-]+", "-", "_".join(str(p) for p in parts))


@dataclass(frozen=True)
class Condition:
    """One point of an experiment's sweep.

    Attributes
    ----------
    index
        Position in the sweep (0-based, file order).
    label
        ``"noise_db=0.5, n_receivers=3"`` (``"base"`` without a sweep).
    params
        ``(short name, value)`` of each swept parameter, in sweep order.
    scenario
        The scenario of this condition (motion included).
    tracker
        Pipeline parameters of this condition.
    """

    index: int
    label: str
    params: tuple[tuple[str, Any], ...]
    scenario: ScenarioConfig
    tracker: TrackerConfig


@dataclass(frozen=True)
class Experiment:
    """A validated experiment (see the module docstring for the file format).

    Attributes
    ----------
    name, title, description
        Identifier (results column ``experiment``), heading and one paragraph.
    seed
        Experiment seed; run ``i`` of every condition uses :func:`run_seed` ``(seed, i)``.
    runs
        Seeded runs per condition.
    methods
        Methods run on every simulated trace.
    kernel
        Likelihood scorer name, or ``"auto"`` (the fastest available).
    conditions
        The sweep's conditions, in order.
    sweep_keys
        Short names of the swept parameters, in sweep order.
    figures
        Figures of the report.
    path
        The file it was read from.
    quick_applied
        Whether the ``[quick]`` overrides are in effect.
    """

    name: str
    title: str
    description: str
    seed: int
    runs: int
    methods: tuple[str, ...]
    kernel: str
    conditions: tuple[Condition, ...]
    sweep_keys: tuple[str, ...]
    figures: tuple[FigureSpec, ...]
    path: str
    quick_applied: bool = False

    def with_runs(self, runs: int) -> Experiment:
        """The same experiment with another number of runs per condition."""
        if runs < 1:
            raise InputError(f"--runs must be at least 1, got {runs}")
        if len(self.conditions) * runs > MAX_TASKS:
            raise InputError(
                f"--runs {runs}: {len(self.conditions):,} conditions × {runs:,} runs is more "
                f"than {MAX_TASKS:,} runs in all"
            )
        return replace(self, runs=int(runs))


# ----------------------------------------------------------------------------- typed reading
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _read_value(sec: Section, name: str, tp: Any) -> Any:
    """Read ``sec[name]`` as the dataclass field type ``tp`` (errors name the key)."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is Literal:
        return sec.string(name, choices=tuple(str(a) for a in args))
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return _read_value(sec, name, inner[0])
    if tp is bool:
        return sec.boolean(name)
    if tp is int:
        return sec.integer(name)
    if tp is float:
        return sec.number(name)
    if tp is str:
        return sec.string(name)
    if origin is tuple and all(a is float for a in args):
        v = sec.numbers(name)
        if len(v) != len(args):
            raise sec.error(name, f"expected {len(args)} numbers, got {len(v)}")
        if len(v) == 2 and v[0] > v[1]:
            raise sec.error(name, f"expected [low, high] with low <= high, got {list(v)}")
        return v
    raise sec.error(name, f"cannot be set from an experiment file (type {tp})")


def _read_table(sec: Section, cls: type, skip: set[str]) -> dict[str, Any]:
    """Values of the keys present in ``sec`` (fields of ``cls``); unknown keys rejected."""
    hints = _hints(cls)
    allowed = {f.name for f in fields(cls)} - skip
    out = {}
    for name in list(sec.data):
        if name in allowed:
            out[name] = _read_value(sec, name, hints[name])
    sec.finish(allowed=allowed)
    return out


def _read_sweep(sec: Section) -> list[tuple[str, str, tuple[Any, ...], str]]:
    """``[(table, field, values, key), ...]`` of a ``[sweep]`` table, in file order.

    Each value is typed like its field; ``key`` is the dotted key, for errors.
    """
    out = []
    for table in list(sec.data):
        if table not in _TABLES:
            continue
        sub = sec.section(table)
        cls, skip = _TABLES[table]
        hints = _hints(cls)
        allowed = {f.name for f in fields(cls)} - skip
        for name in list(sub.data):
            if name not in allowed:
                continue
            raw = sub._get(name, None)
            if not isinstance(raw, list) or not raw:
                raise sub.error(name, "expected a non-empty list of values")
            values = []
            for i, item in enumerate(raw):
                one = Section({name: item}, sec.path, sub.prefix)
                try:
                    values.append(_read_value(one, name, hints[name]))
                except InputError as exc:
                    reason = exc.reason.replace(f"key '{sub.key(name)}': ", "", 1)
                    raise sub.error(name, f"item {i}: {reason}") from None
            if len(set(map(repr, values))) != len(values):
                raise sub.error(name, "values must be distinct")
            out.append((table, name, tuple(values), sub.key(name)))
        sub.finish()
    sec.finish()
    return out


def _read_figures(raw: Any, path: str, prefix: str = "figure") -> list[dict[str, Any]]:
    if not isinstance(raw, list):
        raise InputError(f"key '{prefix}' must be an array of tables ([[{prefix}]])", path=path)
    out = []
    for i, item in enumerate(raw):
        sec = Section(item, path, f"{prefix}[{i}]")
        d: dict[str, Any] = {
            "kind": sec.string("kind", required=True, choices=("error", "reduction", "relative")),
            "x": sec.string("x", required=True),
            "quantity": sec.string("quantity", required=True, choices=("position", "orientation")),
            "hue": sec.string("hue", "method"),
            "title": sec.string("title", None),
            "baseline": sec.string("baseline", None, choices=tuple(METHODS)),
        }
        if sec.has("methods"):
            d["methods"] = _read_methods(sec, "methods")
        if sec.has("reference"):
            ref = sec._get("reference", None)
            if isinstance(ref, bool) or not isinstance(ref, int | float | str):
                raise sec.error("reference", f"expected a number or a string, got {ref!r}")
            d["reference"] = float(ref) if isinstance(ref, int | float) else ref
        if sec.has("where"):
            w = sec.section("where")
            d["where"] = tuple((k, w._get(k, None)) for k in list(w.data))
        sec.finish()
        d["_key"] = sec.prefix
        out.append(d)
    return out


ANCHOR = "textbook"
"""Issue 15's anchor (:mod:`radiopose.evaluate.textbook_pf`), an evaluation-only
method: an experiment may list it in ``methods``; each run registers it told
that run's σ (``scenario.noise_db``, at least 0.01 dB) and the device's power.
Not in the registry, so no site, CLI call or live server can run it; 2-D
experiments only."""


def _estimates_orientation(method: str) -> bool:
    return method == ANCHOR or METHODS[method].estimates_orientation


def _read_methods(sec: Section, name: str) -> tuple[str, ...]:
    raw = sec._get(name, None)
    if not isinstance(raw, list) or not raw:
        raise sec.error(name, "expected a non-empty list of method names")
    for m in raw:
        if m not in METHODS and m != ANCHOR:
            known = ", ".join([*METHODS, ANCHOR])
            raise sec.error(name, f"unknown method {m!r} (known: {known})")
    if len(set(raw)) != len(raw):
        raise sec.error(name, "methods must be distinct")
    return tuple(raw)


# ----------------------------------------------------------------------------- loading
_SETTING = re.compile(r"(?:scenario|tracker) setting (\w+)")


def _build(
    values: dict[str, dict[str, Any]], origins: dict[str, dict[str, str]], path: str
) -> tuple[ScenarioConfig, TrackerConfig]:
    """Configs from per-table values; a range error names the key that set the value."""

    def where(table: str, name: str) -> str:
        return origins[table].get(name, f"{table}.{name} (default)")

    motion = MotionConfig(**values["motion"])
    scenario = ScenarioConfig(**values["scenario"], motion=motion)
    try:
        scenario.validate()
        tracker = TrackerConfig(**values["tracker"])
    except InputError as exc:
        m = _SETTING.search(exc.reason)
        table = "tracker" if exc.reason.startswith("tracker") else "scenario"
        if m:
            raise InputError(f"key '{where(table, m.group(1))}': {exc.reason}", path=path) from None
        raise InputError(exc.reason, path=path) from None
    return scenario, tracker


def _short_names(sweep: list[tuple[str, str, tuple[Any, ...], str]], path: str) -> list[str]:
    names = [name for _, name, _, _ in sweep]
    for n in names:
        if names.count(n) > 1:
            raise InputError(f"key 'sweep': parameter {n!r} is swept twice", path=path)
    return names


def format_value(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, tuple):
        return "[" + ", ".join(format_value(x) for x in v) + "]"
    return str(v)


def _conditions(
    base: dict[str, dict[str, Any]],
    origins: dict[str, dict[str, str]],
    sweep: list[tuple[str, str, tuple[Any, ...], str]],
    path: str,
) -> tuple[Condition, ...]:
    n_conditions = math.prod(len(vals) for _, _, vals, _ in sweep)
    if n_conditions > MAX_CONDITIONS:
        raise InputError(
            f"key 'sweep': {n_conditions:,} conditions "
            f"({' × '.join(str(len(v)) for _, _, v, _ in sweep)}); at most {MAX_CONDITIONS:,}",
            path=path,
        )
    out = []
    combos = itertools.product(*(vals for _, _, vals, _ in sweep)) if sweep else [()]
    for i, combo in enumerate(combos):
        values = {t: dict(v) for t, v in base.items()}
        orig = {t: dict(o) for t, o in origins.items()}
        params = []
        for (table, name, _, key), v in zip(sweep, combo, strict=True):
            values[table][name] = v
            orig[table][name] = key
            params.append((name, v))
        scenario, tracker = _build(values, orig, path)
        label = ", ".join(f"{n}={format_value(v)}" for n, v in params) or "base"
        out.append(Condition(i, label, tuple(params), scenario, tracker))
    return tuple(out)


def _check_figures(
    figs: list[dict[str, Any]],
    sweep_keys: list[str],
    conditions: tuple[Condition, ...],
    methods: tuple[str, ...],
    path: str,
) -> tuple[FigureSpec, ...]:
    out = []
    for d in figs:
        key = d.pop("_key")
        x, hue = d["x"], d["hue"]
        if x not in sweep_keys:
            raise InputError(
                f"key '{key}.x': {x!r} is not a swept parameter "
                f"(swept: {', '.join(sweep_keys) or 'none'})",
                path=path,
            )
        if hue != "method" and (hue not in sweep_keys or hue == x):
            raise InputError(
                f"key '{key}.hue': expected 'method' or another swept parameter, got {hue!r}",
                path=path,
            )
        where = dict(d.get("where", ()))
        for k, v in where.items():
            if k not in sweep_keys or k in (x, hue):
                raise InputError(
                    f"key '{key}.where.{k}': not a swept parameter other than x and hue", path=path
                )
            if not any(_same(dict(c.params)[k], v) for c in conditions):
                raise InputError(f"key '{key}.where.{k}': no condition has {k} = {v!r}", path=path)
        free = [k for k in sweep_keys if k not in (x, hue) and k not in where]
        if free:
            raise InputError(
                f"key '{key}': swept parameter {free[0]!r} varies; fix it in "
                f"'{key}.where' or use it as x or hue",
                path=path,
            )
        chosen = d.get("methods")
        if chosen is not None:
            missing = [m for m in chosen if m not in methods]
            if missing:
                raise InputError(
                    f"key '{key}.methods': {missing[0]!r} is not run by this experiment", path=path
                )
        if hue != "method" and (chosen is None or len(chosen) != 1):
            raise InputError(
                f"key '{key}.methods': with hue = {hue!r} name exactly one method", path=path
            )
        no_orientation = [m for m in chosen or () if not _estimates_orientation(m)]
        if d["quantity"] == "orientation" and no_orientation:
            raise InputError(
                f"key '{key}.methods': {no_orientation[0]} has no orientation", path=path
            )
        if d["kind"] == "reduction":
            base = d.get("baseline") or ("lms" if d["quantity"] == "position" else "top")
            if base not in methods:
                raise InputError(
                    f"key '{key}.baseline': {base!r} is not run by this experiment", path=path
                )
        if (
            d["kind"] == "relative"
            and "reference" in d
            and not any(_same(dict(c.params)[x], d["reference"]) for c in conditions)
        ):
            raise InputError(
                f"key '{key}.reference': no condition has {x} = {d['reference']!r}", path=path
            )
        if "where" in d:
            d["where"] = tuple(d["where"])
        out.append(FigureSpec(**d))
    return tuple(out)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, int | float) and isinstance(b, int | float) and not isinstance(a, bool):
        return abs(float(a) - float(b)) < 1e-9
    return a == b


def _split_quick(doc: dict[str, Any], path: str) -> dict[str, Any]:
    q = doc.get("quick", {})
    if not isinstance(q, dict):
        raise InputError("key 'quick' must be a table", path=path)
    return q


def parse_experiment(doc: dict[str, Any], path: str, quick: bool = False) -> Experiment:
    """Validate a parsed experiment document (see the module docstring).

    Parameters
    ----------
    doc
        The TOML document as a dict.
    path
        The file, for error messages.
    quick
        Apply the ``[quick]`` overrides.
    """
    root = Section(doc, path)
    name = root.string("name", required=True)
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
        raise root.error("name", f"use letters, digits, '_', '-' or '.', got {name!r}")
    title = root.string("title", name)
    description = root.string("description", "")
    seed = root.integer("seed", required=True, low=0, high=2**63 - 1)
    runs = root.integer("runs", 10, low=1, high=100_000)
    methods = _read_methods(root, "methods") if root.has("methods") else METHOD_NAMES
    kernel = root.string("kernel", KERNEL_AUTO)
    _check_kernel(root, kernel)

    base: dict[str, dict[str, Any]] = {}
    origins: dict[str, dict[str, str]] = {}
    for table, (cls, skip) in _TABLES.items():
        sec = root.section(table, required=False)
        base[table] = _read_table(sec, cls, skip)
        origins[table] = {n: sec.key(n) for n in base[table]}
    sweep = _read_sweep(root.section("sweep", required=False))
    figs = _read_figures(root._get("figure", []), path)

    qsec = root.section("quick", required=False)
    q_runs = qsec.integer("runs", None, low=1, high=100_000)
    q_values: dict[str, dict[str, Any]] = {}
    for table, (cls, skip) in _TABLES.items():
        sub = qsec.section(table, required=False)
        q_values[table] = _read_table(sub, cls, skip)
        if quick:
            for n, v in q_values[table].items():
                base[table][n] = v
                origins[table][n] = sub.key(n)
    q_sweep = _read_sweep(qsec.section("sweep", required=False))
    qsec.finish()
    root.finish()

    known = {(t, n) for t, n, _, _ in sweep}
    for t, n, _, key in q_sweep:
        if (t, n) not in known:
            raise InputError(f"key '{key}': {t}.{n} is not swept in [sweep]", path=path)
    if quick:
        runs = q_runs if q_runs is not None else runs
        override = {(t, n): (vals, key) for t, n, vals, key in q_sweep}
        sweep = [(t, n, *override.get((t, n), (vals, key))) for t, n, vals, key in sweep]

    keys = _short_names(sweep, path)
    conditions = _conditions(base, origins, sweep, path)
    if len(conditions) * runs > MAX_TASKS:
        raise InputError(
            f"key 'runs': {len(conditions):,} conditions × {runs:,} runs = "
            f"{len(conditions) * runs:,} runs in all; at most {MAX_TASKS:,}",
            path=path,
        )
    if ANCHOR in methods and any(c.scenario.pose == "3d" for c in conditions):
        raise root.error("methods", f"{ANCHOR!r}, issue 15's anchor, runs at 2-D sites only")
    figures = _check_figures(figs, keys, conditions, methods, path)
    return Experiment(
        name,
        title,
        description,
        seed,
        runs,
        methods,
        kernel,
        conditions,
        tuple(keys),
        figures,
        path,
        quick,
    )


def _check_kernel(root: Section, kernel: str) -> None:
    from radiopose.likelihood import SCORERS

    known = (KERNEL_AUTO, *sorted(SCORERS))
    if kernel not in known:
        raise root.error("kernel", f"expected one of {', '.join(known)}, got {kernel!r}")


def shipped_path(name: str) -> Path:
    """Path of a shipped experiment file (``noise`` → ``…/experiments/noise.toml``)."""
    return Path(str(resources.files("radiopose.evaluate") / "experiments" / f"{name}.toml"))


def load_experiment(
    name_or_path: str | os.PathLike[str], quick: bool = False, runs: int | None = None
) -> Experiment:
    """Load a shipped experiment by name or any experiment TOML file by path.

    Parameters
    ----------
    name_or_path
        One of :data:`SHIPPED` or a path to a ``.toml`` file.
    quick
        Apply the file's ``[quick]`` overrides.
    runs
        Override the number of runs per condition.

    Raises
    ------
    InputError
        Unknown name, unreadable file, or a malformed configuration (naming the key).
    """
    s = str(name_or_path)
    if s in SHIPPED or s in SHIPPED_BEYOND:
        path: Path = shipped_path(s)
    else:
        path = Path(s)
        if not path.exists():
            raise InputError(
                f"no experiment named {s!r} and no such file "
                f"(shipped: {', '.join((*SHIPPED, *SHIPPED_BEYOND))})"
            )
    doc = load_toml(path)
    exp = parse_experiment(doc, str(path), quick=quick)
    parse_experiment(doc, str(path), quick=not quick)  # both variants must be valid
    return exp if runs is None else exp.with_runs(runs)


def is_3d(experiment: Experiment) -> bool:
    """Whether the experiment simulates the 3-D hand-held scenario (``pose = "3d"`` in
    every condition; docs/pose3d.md): its rows carry per-axis errors."""
    return all(c.scenario.pose == "3d" for c in experiment.conditions)
