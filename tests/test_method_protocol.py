"""The method registry: every method follows the protocol, front ends read its
attributes (not names), a new method plugs in through :func:`register_method`,
and scorers declare their optional features."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np
import pytest

from radiopose.errors import InputError
from radiopose.estimates import POSITION_ONLY_METHODS
from radiopose.evaluate.demo import run_methods
from radiopose.likelihood import (
    HeardRss,
    MemoScorer,
    ReferenceScorer,
    TableScorer,
    candidate_space,
    make_scorer,
)
from radiopose.packets import group_packets
from radiopose.tracker import (
    METHOD_NAMES,
    METHODS,
    PAPER_METHODS,
    SKIP_ACQUIRING,
    Device,
    Evidence,
    Method,
    Outcome,
    Step,
    Tracker,
    TrackState,
    get_method,
    locate,
    needs_scorer,
    register_method,
)
from radiopose.tracker_settings import load_site_live_method, read_tracker_toml


def test_every_method_follows_the_protocol():
    assert METHOD_NAMES == tuple(METHODS) == (*PAPER_METHODS, "filter")
    for name, m in METHODS.items():
        assert isinstance(m, Method) and m.name == name and m.label
        assert m.evidence and m.evidence <= set(Evidence)
    assert {m for m in METHODS if not METHODS[m].estimates_orientation} == POSITION_ONLY_METHODS
    assert [m for m in METHODS if not needs_scorer(METHODS[m])] == ["lms"]
    assert [m for m in METHODS if METHODS[m].lagged] == ["filter"]
    assert [m for m in METHODS if METHODS[m].acquires] == ["full", "location", "orientation"]
    with pytest.raises(InputError, match=r"unknown method 'magic'.*known: full"):
        get_method("magic")


def test_acquisition_follows_the_attribute_not_the_name(small_sim):
    top = METHODS["top"]
    plain = locate(small_sim.site, small_sim.packets, top)
    assert SKIP_ACQUIRING not in dict(plain.summary.skipped)
    pooled = locate(small_sim.site, small_sim.packets, replace(top, acquires=True))
    assert dict(pooled.summary.skipped)[SKIP_ACQUIRING] > 0
    assert len(pooled.estimates) < len(plain.estimates)


def test_a_stored_state_of_another_method_starts_afresh(small_sim):
    obs = group_packets(small_sim.packets)
    tr = Tracker(small_sim.site, "filter")
    key = small_sim.site.devices[0].transmitter.lower()
    tr.states[key] = TrackState(0.0, 0.0, (1.0, 1.0, 1.0))  # a checkpoint of ``full``
    est, reason = tr.update(obs[0])
    assert reason is None and est is not None and est.method == "filter"


# -- the example of docs/methods.md ------------------------------------------------
@dataclass(frozen=True)
class Strongest:
    """Position of the receiver that heard the packet loudest (a toy)."""

    name: str = "strongest"
    label: str = "the loudest receiver's position"
    evidence: frozenset[Evidence] = frozenset({Evidence.RSS})
    estimates_orientation: bool = False
    acquires: bool = False
    lagged: bool = False
    state_type: type = field(default=type(None))

    def prepare(self, device: Device) -> None:
        device.engine = device.site.receiver_positions_m()

    def new_state(self, device: Device) -> None:
        return None

    def step(
        self, device: Device, state: None, heard: HeardRss, t_s: float, packet_id: str
    ) -> Step:
        loudest = heard.receiver_index[np.argmax(heard.rss_dbm)]
        xyz = tuple(float(v) for v in device.engine[loudest])
        return Step(None, Outcome(xyz, (0.0, 0.0, 0.0)))

    def flush(self, device: Device, state: None) -> tuple[()]:
        return ()


@pytest.fixture
def strongest() -> Iterator[Strongest]:
    m = Strongest()
    register_method(m)
    try:
        yield m
    finally:
        del METHODS[m.name]


def test_a_registered_method_runs_everywhere(strongest, small_sim):
    res = locate(small_sim.site, small_sim.packets, "strongest")
    assert res.summary.coverage == 1.0 and set(res.estimates.method) == {"strongest"}
    rx = small_sim.site.receiver_positions_m()
    assert all(any(np.allclose(p, r) for r in rx) for p in res.estimates.position_m)
    run = run_methods(small_sim, ("strongest", "top"))["strongest"]
    assert run.orientation_error_deg.size == 0  # not an orientation estimate
    assert run.position_error_m.size == len(res.estimates)
    with pytest.raises(ValueError, match="already registered"):
        register_method(strongest)
    with pytest.raises(ValueError, match="lower-case word"):
        register_method(replace(strongest, name="Loud One"))
    with pytest.raises(ValueError, match="protocol"):
        register_method(object())


# -- scorer features -----------------------------------------------------------------
def test_scorers_declare_their_optional_features(small_sim):
    space = candidate_space(small_sim.site, small_sim.site.devices[0].transmitter)
    heard = space.heard(group_packets(small_sim.packets)[0])
    for plain in (ReferenceScorer(space), TableScorer(space)):
        assert not plain.supports_window and not plain.supports_position_mse
        with pytest.raises(NotImplementedError, match="window"):
            plain.score_window(heard, 5, np.arange(3), 0.0, 30.0)
        memo = MemoScorer(plain)
        assert not memo.supports_window and not memo.supports_position_mse
    compiled = make_scorer("numba", space)
    memo = MemoScorer(compiled)
    assert compiled.supports_window and compiled.supports_position_mse
    assert memo.supports_window and memo.supports_position_mse
    np.testing.assert_array_equal(memo.position_mse_db2(heard), compiled.position_mse_db2(heard))


def test_a_site_chooses_its_live_method(tmp_path):
    toml = tmp_path / "tracker.toml"
    assert load_site_live_method(tmp_path) is None
    toml.write_text('live_method = "filter"\n')
    assert load_site_live_method(tmp_path) == "filter"
    assert read_tracker_toml(toml) == ({}, None)
    toml.write_text('smoothing_lag_s = 2.0\nlive_method = "magic"\n')
    with pytest.raises(InputError, match=r"tracker.toml:2, column .live_method.*magic"):
        load_site_live_method(tmp_path)
    with pytest.raises(InputError, match="live_method"):
        read_tracker_toml(toml)
