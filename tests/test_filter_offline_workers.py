"""The offline passes on a second process (``FilterConfig.offline_workers``; issue 15,
whole-process speed; docs/performance.md "Eighth pass").

Parallel equals serial: the same seeded runs with ``offline_workers`` 1 and 2
give the same estimates bit for bit, matched (the reversed pass run by the
look-ahead child) and 6 dB loud (the offset selection's passes spread over two
processes); the look-ahead's result is used (the parent does not run the
reversed pass again) unless the packets it was given are not the ones the
forward pass kept. The fork helper re-runs a call whose child died and raises
a call's own error here. Identical candidates are refined once by the arbiter.
The setting is checked with one-line errors. The streaming ``Tracker`` (the
live path) never forks.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import radiopose.filtering.forked as forked
import radiopose.filtering.offset as offset
import radiopose.filtering.refine2d as refine2d
import radiopose.filtering.reverse as reverse
from radiopose.errors import InputError
from radiopose.estimates import Estimates
from radiopose.filtering import FilterConfig
from radiopose.packets import Packets, group_packets
from radiopose.simulate import ScenarioConfig, simulate
from radiopose.tracker import Tracker, TrackerConfig, locate
from radiopose.tracker.filter import _same_records
from radiopose.tracker_settings import read_tracker_settings

SMALL = ScenarioConfig(
    size_m=10.0, step_m=0.25, duration_s=1.5, min_receiver_spacing_m=3.0, noise_db=1.0
)

needs_fork = pytest.mark.skipif(forked.effective_workers(2) < 2, reason="needs fork and two cores")


@pytest.fixture(autouse=True)
def _numba_allows_fork(monkeypatch: pytest.MonkeyPatch) -> None:
    """Earlier tests of the session may have launched numba's GNU OpenMP layer,
    after which a real run does not fork (:func:`forked.numba_fork_safe`);
    these tests' children never enter a parallel region (plain ``locate``: the
    filter's one-thread scorer, ``serial_only``), so forking is safe here."""
    monkeypatch.setattr(forked, "numba_fork_safe", lambda: True)


def _config(workers: int) -> TrackerConfig:
    base = TrackerConfig()
    return replace(base, filter=replace(base.filter, offline_workers=workers))


def _loud(packets: Packets, db: float) -> Packets:
    return Packets(
        packets.packet_id, packets.timestamp_s, packets.transmitter, packets.receiver_id,
        packets.rss_dbm + db,
    )  # fmt: skip


def _assert_same(a: Estimates, b: Estimates) -> None:
    assert len(a) == len(b) > 0
    for name in ("timestamp_s", "packet_id", "position_m", "orientation_deg"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for name in ("position_std_m", "azimuth_std_deg"):
        x, y = getattr(a, name), getattr(b, name)
        assert x is not None and y is not None
        np.testing.assert_array_equal(x, y, err_msg=name)


class _Count:
    """Counts calls of a module function in this process (children not seen)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, module: object, name: str) -> None:
        self.n = 0
        f = getattr(module, name)

        def counted(*a: object, **k: object) -> object:
            if os.getpid() == self.pid:
                self.n += 1
            return f(*a, **k)

        self.pid = os.getpid()
        monkeypatch.setattr(module, name, counted)


@pytest.fixture(scope="module")
def sim():
    return simulate(SMALL, 7003)


# ----------------------------------------------------------------- the setting
@pytest.mark.parametrize("bad", [0, -1, 65, 1.5, True, "2"])
def test_offline_workers_is_checked(bad: object) -> None:
    with pytest.raises(InputError) as exc:
        FilterConfig(offline_workers=bad)  # type: ignore[arg-type]
    msg = str(exc.value)
    assert "offline_workers" in msg and "\n" not in msg


def test_offline_workers_in_tracker_toml(tmp_path: Path) -> None:
    p = tmp_path / "tracker.toml"
    p.write_text("[filter]\noffline_workers = 1\n", encoding="utf-8")
    assert read_tracker_settings(p).filter_overrides == {"offline_workers": 1}
    p.write_text("[filter]\noffline_workers = 0\n", encoding="utf-8")
    with pytest.raises(InputError) as exc:
        read_tracker_settings(p)
    assert "offline_workers" in str(exc.value) and "\n" not in str(exc.value)
    assert exc.value.path == str(p)


def test_default_and_effective_workers() -> None:
    assert FilterConfig().offline_workers == 2
    assert forked.effective_workers(1) == 1
    assert 1 <= forked.effective_workers(64) <= forked.available_cores()


# ------------------------------------------------------------- the fork helper
@needs_fork
def test_map_forked_equals_serial_in_order() -> None:
    calls = [lambda i=i: (i, os.getpid(), np.arange(i)) for i in range(7)]
    out = forked.map_forked(calls, 2, weights=[7, 1, 1, 1, 1, 1, 1])
    assert [o[0] for o in out] == list(range(7))
    for i, o in enumerate(out):
        np.testing.assert_array_equal(o[2], np.arange(i))
    assert len({o[1] for o in out}) == 2  # some ran in a child
    assert os.getpid() in {o[1] for o in out}  # and some here


@needs_fork
def test_a_dead_child_is_run_again_here_and_an_error_is_raised_here() -> None:
    here = os.getpid()

    def dies_in_a_child() -> int:
        if os.getpid() != here:
            os._exit(3)
        return 5

    assert forked.map_forked([lambda: 1, dies_in_a_child], 2) == [1, 5]

    def refuses() -> int:
        raise InputError("no such packet")

    with pytest.raises(InputError, match="no such packet"):
        forked.map_forked([lambda: 1, refuses], 2)
    job = forked.ForkedCall(refuses)
    with pytest.raises(forked.ChildFailedError, match="InputError: no such packet"):
        job.result()


# ------------------------------------------------------- parallel equals serial
@needs_fork
def test_parallel_equals_serial_matched(sim, monkeypatch: pytest.MonkeyPatch) -> None:
    serial = locate(sim.site, sim.packets, "filter", _config(1)).estimates
    forks = _Count(monkeypatch, forked.ForkedCall, "__init__")
    parent_reversed = _Count(monkeypatch, reverse, "run_reversed")
    parallel = locate(sim.site, sim.packets, "filter", _config(2)).estimates
    _assert_same(serial, parallel)
    assert forks.n >= 1  # the look-ahead's child (and the arbiter's, if it had two candidates)
    assert parent_reversed.n == 0  # the look-ahead's reversed pass was used


@needs_fork
def test_parallel_equals_serial_with_the_offset_selection(
    sim, monkeypatch: pytest.MonkeyPatch
) -> None:
    loud = _loud(sim.packets, 6.0)
    serial = locate(sim.site, loud, "filter", _config(1)).estimates
    forks = _Count(monkeypatch, forked.ForkedCall, "__init__")
    spread: list[int] = []
    real = offset.map_forked

    def seen(fns, workers, weights=None):  # type: ignore[no-untyped-def]
        spread.append(len(fns))
        return real(fns, workers, weights)

    monkeypatch.setattr(offset, "map_forked", seen)
    parallel = locate(sim.site, loud, "filter", _config(2)).estimates
    _assert_same(serial, parallel)
    assert spread and spread[0] >= 2  # the selection ran two or more tight passes
    assert forks.n >= 2  # the look-ahead and the tight passes


@needs_fork
def test_a_look_ahead_on_other_packets_is_not_used(sim, monkeypatch: pytest.MonkeyPatch) -> None:
    obs = group_packets(sim.packets)
    serial = locate(sim.site, sim.packets, "filter", _config(1)).estimates
    parent_reversed = _Count(monkeypatch, reverse, "run_reversed")
    tr = Tracker(sim.site, "filter", _config(2), lag_s=1.0, offline=True)
    tr.look_ahead(obs[:-3])  # not the packets the forward pass will keep
    found = {}
    for o in obs:
        tr.update(o)
        found.update({d.packet_id: d for d in tr.take_delayed()})
    found.update({d.packet_id: d for d in tr.flush()})
    assert parent_reversed.n == 1  # run again here
    ids = list(serial.packet_id)
    pos = np.array([found[i].position_m for i in ids])
    ori = np.array([found[i].orientation_deg for i in ids])
    np.testing.assert_array_equal(pos, serial.position_m)
    np.testing.assert_array_equal(ori, serial.orientation_deg)


def test_same_records_compares_keys_times_and_readings(sim) -> None:
    tr = Tracker(sim.site, "filter", _config(1), lag_s=1.0, offline=True)
    obs = group_packets(sim.packets)[:3]
    dev = tr.device(obs[0].transmitter)
    recs = [(o.timestamp_s, dev.space.heard(o), (o.packet_id, o.timestamp_s)) for o in obs]
    again = [(t, dev.space.heard(o), k) for (t, _, k), o in zip(recs, obs, strict=True)]
    assert _same_records(recs, again)
    assert not _same_records(recs, recs[:2])
    h = recs[1][1]
    louder = type(h)(h.receiver_index, h.rss_dbm + 0.5)
    assert not _same_records(recs, [recs[0], (recs[1][0], louder, recs[1][2]), recs[2]])


# --------------------------------------------------------------- the arbiter
def test_identical_candidates_are_refined_once(sim, monkeypatch: pytest.MonkeyPatch) -> None:
    tr = Tracker(sim.site, "filter", _config(1), lag_s=1.0, offline=True)
    obs = group_packets(sim.packets)
    dev = tr.device(obs[0].transmitter)
    pf = dev.engine
    recs = [(o.timestamp_s, dev.space.heard(o), (o.packet_id, o.timestamp_s)) for o in obs]
    recs = [r for r in recs if r[1].n_heard > 0]
    st = pf.new_state(1)
    for t, h, k in recs:
        pf.step(st, t, h, k)
    pf.flush(st)
    first = dict(pf.take_smoothed())
    shifted = {
        k: replace(e, position_m=(e.position_m[0] + 0.3, *e.position_m[1:]))
        for k, e in first.items()
    }
    calls = _Count(monkeypatch, refine2d, "refine_track_2d")
    cfg = pf.config
    out2, log2 = refine2d.arbitrate(pf.model, recs, [first, shifted], 1.0, cfg, 5)
    assert calls.n == len(log2) * 2
    calls.n = 0
    out4, log4 = refine2d.arbitrate(
        pf.model, recs, [first, dict(first), shifted, dict(shifted)], 1.0, cfg, 5
    )
    assert calls.n == len(log4) * 2  # the copies are not refined again
    assert out4 == out2
    assert [(a.costs[0], a.costs[2]) for a in log4] == [a.costs for a in log2]
    assert all(a.costs[0] == a.costs[1] and a.costs[2] == a.costs[3] for a in log4)


# ------------------------------------------------------------ the live path
def test_the_streaming_tracker_never_forks(sim, monkeypatch: pytest.MonkeyPatch) -> None:
    forks = _Count(monkeypatch, forked.ForkedCall, "__init__")
    tr = Tracker(sim.site, "filter", _config(2), lag_s=0.25)  # as the live server
    for o in group_packets(sim.packets):
        tr.update(o)
    tr.flush()
    assert forks.n == 0


@needs_fork
def test_a_running_child_takes_the_spare_core(monkeypatch: pytest.MonkeyPatch) -> None:
    import math

    import radiopose.likelihood.compiled as compiled

    monkeypatch.setenv("NUMBA_NUM_THREADS", "2")
    monkeypatch.setattr(compiled, "_SPARE", [math.inf, True])  # "the machine is idle"
    assert compiled.spare_core()
    job = forked.ForkedCall(compiled.spare_core)
    assert not compiled.spare_core()  # the parent's compiled work stays on one thread
    assert job.result() is False  # and so does the child's
    assert compiled.spare_core()
    job = forked.ForkedCall(lambda: 1)
    job.cancel()
    assert compiled.spare_core()


@needs_fork
def test_look_ahead_children_are_bounded_and_die_with_their_owner(sim) -> None:
    import gc
    import time

    from radiopose.tracker.filter import _ahead_key, _core_free, _LookAhead

    tr = Tracker(sim.site, "filter", _config(2), lag_s=1.0, offline=True)
    obs = group_packets(sim.packets)
    tr.look_ahead(obs)
    dev = next(iter(tr._devices.values()))
    ahead = dev.shared[_ahead_key(dev)]
    assert isinstance(ahead, _LookAhead) and ahead.job is None and ahead.pending()
    assert _core_free(dev)
    ahead.start(lambda: time.sleep(60))  # type: ignore[arg-type,return-value]
    assert ahead.running()
    assert not _core_free(dev)  # offline_workers = 2: one look-ahead child at a time
    assert ahead.job is not None
    pid = ahead.job.pid
    assert pid is not None
    del dev.shared[_ahead_key(dev)], ahead
    gc.collect()
    for _ in range(50):  # killed when dropped untaken
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        pytest.fail("the dropped look-ahead's child still runs")


@needs_fork
def test_a_late_look_ahead_leaves_the_forward_refinement_to_the_parent(
    sim, monkeypatch: pytest.MonkeyPatch
) -> None:
    import time

    import radiopose.tracker.filter as tf

    serial = locate(sim.site, sim.packets, "filter", _config(1)).estimates
    real = tf.run_reversed

    def late(*a, **k):  # type: ignore[no-untyped-def]
        time.sleep(3.0)  # the forward pass ends first
        return real(*a, **k)

    monkeypatch.setattr(tf, "run_reversed", late)
    batches: list[list[bytes]] = []  # each map_forked call's refinements (their poses)
    real_map = refine2d.map_forked

    def seen(fns, workers, weights=None):  # type: ignore[no-untyped-def]
        batches.append([f.args[3].tobytes() for f in fns])
        return real_map(fns, workers, weights)

    monkeypatch.setattr(refine2d, "map_forked", seen)
    parallel = locate(sim.site, sim.packets, "filter", _config(2)).estimates
    _assert_same(serial, parallel)
    # the forward track refined while the child finished, then only the others
    assert len(batches) == 2 and len(batches[0]) == 1
    everything = [b for batch in batches for b in batch]
    assert len(everything) == len(set(everything))  # nothing refined twice


def test_no_fork_in_a_daemonic_process(monkeypatch: pytest.MonkeyPatch) -> None:
    """A Dask worker of ``radiopose evaluate`` is daemonic: it may not have
    children, so every call runs in it."""
    from types import SimpleNamespace

    monkeypatch.setattr(
        forked.multiprocessing, "current_process", lambda: SimpleNamespace(daemon=True)
    )
    assert not forked.fork_available()
    assert forked.effective_workers(2) == 1
    assert forked.try_fork(lambda: 1) is None
    out = forked.map_forked([os.getpid, os.getpid, os.getpid], 2)
    assert out == [os.getpid()] * 3


def test_no_fork_after_gnu_openmp_was_launched(monkeypatch: pytest.MonkeyPatch) -> None:
    import numba

    monkeypatch.undo()  # the real check, not the autouse fixture's
    for layer, safe in (("omp", False), ("workqueue", True), ("tbb", True)):
        monkeypatch.setattr(numba, "threading_layer", lambda layer=layer: layer)
        assert forked.numba_fork_safe() is safe

    def not_launched() -> str:
        raise ValueError("Threading layer is not initialized.")

    monkeypatch.setattr(numba, "threading_layer", not_launched)
    assert forked.numba_fork_safe()
    monkeypatch.setattr(numba, "threading_layer", lambda: "omp")
    assert not forked.fork_available()
    assert forked.try_fork(lambda: 1) is None


@needs_fork
def test_a_child_computes_the_exact_mse_on_one_thread() -> None:
    from radiopose.likelihood import exact

    assert forked.ForkedCall(lambda: exact._SERIAL_ONLY[0]).result() is True
    assert exact._SERIAL_ONLY[0] is False  # the parent keeps its threads
