"""Methods from outside the package (docs/methods.md, "Methods from outside the
package"): loaded from ``RADIOPOSE_METHODS`` (and entry points) in every
process, their failures and contract breaches named, and the live server kept
going when one device's method fails."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import threading
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from radiopose.errors import InputError, MethodError
from radiopose.evaluate.figures import METHOD_STYLE, method_style
from radiopose.evaluate.scoring import position_only
from radiopose.server.app import import_site_dir
from radiopose.server.db import Database
from radiopose.server.demo import _stopped
from radiopose.server.live import LivePipeline
from radiopose.server.worker import method_missing
from radiopose.tracker import (
    METHODS,
    PLUGINS_ENV,
    SKIP_METHOD_FAILED,
    Device,
    Evidence,
    Outcome,
    Step,
    Tracker,
    load_plugins,
    locate,
    register_method,
)
from radiopose.tracker.registry import _LOADED
from server_support import fast_live, store_frames, tiny  # tiny: a fixture

PLUGIN = textwrap.dedent(
    '''
    """A plugin for the tests: the loudest receiver's position, azimuth 90°."""
    from dataclasses import dataclass, field

    import numpy as np

    from radiopose.tracker import Evidence, Outcome, Step


    @dataclass(frozen=True)
    class Loudest:
        name: str = "loudest-plug"
        label: str = "the loudest receiver's position (a test plugin)"
        evidence: frozenset = frozenset({Evidence.RSS})
        estimates_orientation: bool = True
        acquires: bool = False
        lagged: bool = False
        state_type: type = field(default=type(None))

        def prepare(self, device):
            device.engine = device.site.receiver_positions_m()

        def new_state(self, device):
            return None

        def step(self, device, state, heard, t_s, packet_id):
            xyz = device.engine[heard.receiver_index[np.argmax(heard.rss_dbm)]]
            return Step(None, Outcome(tuple(float(v) for v in xyz), (90.0, 0.0, 0.0)))

        def flush(self, device, state):
            return ()


    LOUDEST = Loudest()
    '''
)


def _cli(env_methods: str, tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    import os

    env = {**os.environ, PLUGINS_ENV: env_methods, "PYTHONPATH": str(tmp_path)}
    return subprocess.run(
        [sys.executable, "-m", "radiopose", *args],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )


def test_a_plugin_named_in_the_variable_runs_from_the_command_line(tiny, tmp_path: Path) -> None:
    (tmp_path / "rp_test_plugin.py").write_text(PLUGIN, encoding="utf-8")
    out = tmp_path / "est.csv"
    packets = tiny.root / "packets.csv"
    r = _cli("rp_test_plugin:LOUDEST", tmp_path, "locate", str(tiny.site_dir), str(packets),
             "-o", str(out), "--method", "loudest-plug", "--quiet")  # fmt: skip
    assert r.returncode == 0, r.stderr
    rows = out.read_text().splitlines()
    assert len(rows) > 100 and all(row.endswith(",loudest-plug") for row in rows[1:])
    assert ",90," in rows[1]
    r = _cli("rp_test_plugin:LOUDEST", tmp_path, "methods")
    listed = {ln.split()[0]: ln for ln in r.stdout.splitlines()[1:]}
    assert list(listed)[:6] == ["full", "location", "orientation", "top", "lms", "filter"]
    assert "rp_test_plugin:LOUDEST" in listed["loudest-plug"] and "built-in" in listed["lms"]
    # without the variable the name is unknown (nothing is registered by accident)
    r = _cli("", tmp_path, "locate", str(tiny.site_dir), str(packets), "-o", str(out),
             "--method", "loudest-plug")  # fmt: skip
    assert r.returncode == 2 and "loudest-plug" in r.stderr


@pytest.mark.parametrize(
    ("spec", "words"),
    [
        ("rp_no_such_module", "ModuleNotFoundError"),
        ("rp_test_plugin:NOPE", "AttributeError"),
        ("rp_test_plugin:Loudest", "a class, not a method object"),
    ],
)
def test_a_bad_plugin_is_one_line_naming_the_variable(
    tiny, tmp_path: Path, spec: str, words: str
) -> None:
    (tmp_path / "rp_test_plugin.py").write_text(PLUGIN, encoding="utf-8")
    r = _cli(spec, tmp_path, "locate", str(tiny.site_dir), str(tiny.root / "packets.csv"),
             "-o", str(tmp_path / "e.csv"), "--method", "full")  # fmt: skip
    assert r.returncode == 2, r.stderr
    (line,) = r.stderr.strip().splitlines()
    assert line.startswith(f"radiopose: {PLUGINS_ENV} entry {spec!r}: ") and words in line
    assert "Traceback" not in r.stderr


def test_a_plugin_imported_before_the_registry_is_registered_when_asked_for(
    tmp_path: Path,
) -> None:
    """A plugin module imported first (its own tests, a notebook) imports
    radiopose.tracker, whose import loads the plugins while the module is still
    importing: it is deferred (it failed with "partially initialized module")
    and registered by the first lookup."""
    (tmp_path / "rp_test_plugin.py").write_text(PLUGIN, encoding="utf-8")
    code = (
        "import rp_test_plugin\n"
        "from radiopose.tracker import get_method, METHODS\n"
        "print(get_method('loudest-plug') is rp_test_plugin.LOUDEST, 'loudest-plug' in METHODS)\n"
    )
    import os

    env = {**os.environ, PLUGINS_ENV: "rp_test_plugin:LOUDEST", "PYTHONPATH": str(tmp_path)}
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["True", "True"]


def test_a_plugin_failing_after_registering_leaves_nothing(tmp_path: Path, monkeypatch) -> None:
    (tmp_path / "rp_test_plugin_bad.py").write_text(
        PLUGIN.replace("loudest-plug", "loudest-bad")
        + "\nfrom radiopose.tracker import register_method\nregister_method(LOUDEST)\n"
        + "raise RuntimeError('broken after registering')\n",
        encoding="utf-8",
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv(PLUGINS_ENV, "rp_test_plugin_bad")
    for _ in range(2):  # the second attempt reports the same error, not "already registered"
        with pytest.raises(InputError, match="RuntimeError: broken after registering"):
            load_plugins()
        assert "loudest-bad" not in METHODS


def test_load_plugins_registers_once_per_spec(tmp_path: Path, monkeypatch) -> None:
    (tmp_path / "rp_test_plugin_b.py").write_text(
        PLUGIN.replace("loudest-plug", "loudest-b"), encoding="utf-8"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv(PLUGINS_ENV, " rp_test_plugin_b:LOUDEST , ")
    try:
        assert load_plugins() == ("loudest-b",)
        first = METHODS["loudest-b"]
        assert load_plugins() == ("loudest-b",) and METHODS["loudest-b"] is first
    finally:
        METHODS.pop("loudest-b", None)
        _LOADED.pop("rp_test_plugin_b:LOUDEST", None)


# ----------------------------------------------------------------------------- names
@dataclass(frozen=True)
class Probe:
    """A test method whose answers the tests choose: ``answer(k)`` for the
    device's ``k``-th packet of its track (0-based) with id ``packet_id`` is an
    :class:`Outcome` (``None``: a fixed pose) or an exception to raise."""

    name: str = "probe"
    label: str = "a test probe"
    evidence: frozenset[Evidence] = frozenset({Evidence.RSS})
    estimates_orientation: bool = True
    acquires: bool = False
    lagged: bool = False
    state_type: type = int
    answer: Any = None
    unpicklable: bool = False

    def prepare(self, device: Device) -> None:
        device.engine = device.site.receiver_positions_m()

    def new_state(self, device: Device) -> Any:
        return threading.Lock() if self.unpicklable else 0

    def step(self, device, state, heard, t_s, packet_id) -> Step:  # type: ignore[no-untyped-def]
        k = 0 if self.unpicklable else state
        got = self.answer(k, packet_id) if self.answer is not None else None
        if isinstance(got, Exception):
            raise got
        out = got or Outcome((1.0, 2.0, 0.0), (10.0, 0.0, 0.0))
        return Step(state if self.unpicklable else state + 1, out)

    def flush(self, device, state) -> tuple[()]:  # type: ignore[no-untyped-def]
        return ()


@pytest.fixture
def registered():  # type: ignore[no-untyped-def]
    names: list[str] = []

    def add(method: Probe) -> str:
        register_method(method, replace=True)
        names.append(method.name)
        return method.name

    yield add
    for n in names:
        METHODS.pop(n, None)


def test_names_the_database_cannot_store_or_the_anchor_are_refused() -> None:
    with pytest.raises(ValueError, match="at most 16"):
        register_method(Probe(name="a-seventeen-chars"))
    with pytest.raises(ValueError, match="reserved"):
        register_method(Probe(name="textbook"))
    with pytest.raises(ValueError, match="lower-case word"):
        register_method(Probe(name="nnfp é"))
    assert "a-seventeen-chars" not in METHODS and "textbook" not in METHODS


# ----------------------------------------------------------------------------- answers
def _packets(tiny):  # type: ignore[no-untyped-def]
    from radiopose.packets import read_packets_csv
    from radiopose.site import load_site

    return load_site(tiny.site_dir), read_packets_csv(tiny.root / "packets.csv")


@pytest.mark.parametrize(
    ("answer", "words"),
    [
        (lambda k, _p: RuntimeError("boom") if k == 3 else None, "failed at packet"),
        (lambda k, _p: Outcome((1.0, float("nan"), 0.0), (0.0, 0.0, 0.0)), "non-finite pose"),
        (lambda k, _p: Outcome((1.0, 2.0, 0.0), None), "without a position"),
        (lambda k, _p: Outcome((1.0, 2.0), (0.0, 0.0, 0.0)), "without a position"),
        (
            lambda k, _p: Outcome((1.0, 2.0, 0.0), (0.0, 0.0, 0.0), position_std_m=-1.0),
            "uncertainty",
        ),
    ],
)
def test_a_plugin_failure_or_a_bad_answer_is_a_method_error(
    tiny, registered, answer, words: str
) -> None:
    site, packets = _packets(tiny)
    name = registered(Probe(answer=answer))
    with pytest.raises(MethodError) as err:
        locate(site, packets, name)
    msg = str(err.value)
    assert f"method {name!r}" in msg and words in msg and "\n" not in msg
    assert tiny.transmitter.lower() in msg.lower()


def test_a_position_only_plugin_reads_zero_orientation_and_is_not_scored(tiny, registered) -> None:
    site, packets = _packets(tiny)
    name = registered(
        Probe(
            name="probe-pos", estimates_orientation=False, answer=lambda k, _p: Outcome((1, 2, 0))
        )
    )
    est = locate(site, packets, name).estimates
    assert len(est) > 100 and np.all(est.orientation_deg == 0.0)
    assert position_only(name) and position_only("lms") and not position_only("full")


# ----------------------------------------------------------------------------- live
def _run_live(tiny, tmp_path: Path, method: str) -> tuple[Database, LivePipeline]:  # type: ignore[no-untyped-def]
    """The tiny trace's frames stored and stepped through a live pipeline of
    ``method`` until every batch is processed (a stall fails)."""
    db = Database(f"sqlite:///{tmp_path / 'live.db'}")
    import_site_dir(db, tiny.site_dir)
    n = store_frames(db, tiny, per_batch=20)
    p = LivePipeline(db, fast_live(method=method, checkpoint_s=0.0, idle_flush_s=1e6))
    for _ in range(n + 5):
        p.step()
    assert p.state.cursor == n
    return db, p


def test_live_a_failing_method_skips_the_packet_and_restarts_the_track(
    tiny, registered, tmp_path: Path
) -> None:
    """The method raises on one packet: that packet is stored with
    SKIP_METHOD_FAILED, the device starts afresh and later packets get
    estimates; the pipeline does not stall (it once raised out of every step
    and retried the same batch forever)."""
    name = registered(Probe(answer=lambda k, p: RuntimeError("boom") if p == "5" else None))
    db, p = _run_live(tiny, tmp_path, name)
    reasons = [row["reason"] for row in db.packets()]
    assert reasons.count(SKIP_METHOD_FAILED) == 1
    first_fail = reasons.index(SKIP_METHOD_FAILED)
    assert first_fail == 5 and reasons[first_fail + 1 :].count(None) > 50
    assert p.state.counts["method_failures"] == 1
    assert len(db.estimates(limit=10**6)) == sum(r is None for r in reasons)
    db.close()


def test_live_a_state_that_does_not_pickle_is_dropped_not_a_stall(
    tiny, registered, tmp_path: Path
) -> None:
    name = registered(Probe(name="probe-lock", unpicklable=True))
    db, p = _run_live(tiny, tmp_path, name)
    assert p.state.counts["method_failures"] >= 1
    assert len(db.estimates(limit=10**6)) > 100  # every step committed its estimates
    db.close()


def test_the_pipeline_process_names_a_method_it_does_not_have() -> None:
    from radiopose.server.live import LiveConfig

    assert method_missing(LiveConfig()) is None
    assert method_missing(LiveConfig(method="full")) is None
    why = method_missing(replace(LiveConfig(), method="nnfp"))
    assert why is not None and "unknown method 'nnfp'" in why and PLUGINS_ENV in why


def test_the_live_demo_says_why_its_server_stopped(tmp_path: Path) -> None:
    log = tmp_path / "server.log"
    log.write_text("radiopose: --method must be one of full, top, got 'nnfp'\n")
    assert _stopped(log, 8123).startswith("the server stopped: --method must be one of")
    log.write_text("ERROR: [Errno 98] error while attempting to bind: address already in use\n")
    assert "port 8123 is taken" in _stopped(log, 8123)
    assert "is port 8123 free?" in _stopped(tmp_path / "none.log", 8123)


def test_figures_give_unknown_methods_styles_no_built_in_uses() -> None:
    others: list[str] = []
    styles = [method_style(m, others) for m in ("full", "nnfp", "other", "nnfp")]
    assert styles[0] == METHOD_STYLE["full"] and styles[1] == styles[3]
    assert styles[1] != styles[2] and not {styles[1], styles[2]} & set(METHOD_STYLE.values())


def test_tracker_state_of_a_dropped_device_starts_afresh(tiny, registered) -> None:
    site, packets = _packets(tiny)
    from radiopose.packets import group_packets

    name = registered(Probe())
    tr = Tracker(site, name)
    obs = group_packets(packets)
    for o in obs[:3]:
        tr.update(o)
    key = tiny.transmitter.lower()
    assert tr.states[key] == 3
    tr.drop(tiny.transmitter)
    tr.update(obs[3])
    assert tr.states[key] == 1
