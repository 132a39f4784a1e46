"""The lms baseline: log-distance fit to the survey and least-squares positioning."""

from __future__ import annotations

import numpy as np
import pytest

from radiopose.baselines import LmsLocator, fit_log_distance
from radiopose.simulate import ScenarioConfig, simulate


@pytest.fixture(scope="module")
def sim():
    return simulate(ScenarioConfig(size_m=12.0, step_m=0.5, duration_s=0.05), seed=5)


def test_fit_recovers_the_simulated_exponent(sim):
    fit = fit_log_distance(sim.site)
    # Simulated channel: n = 3, PL(1 m) = 40 dB; patterns add a few dB of scatter.
    np.testing.assert_allclose(fit.exponent, 3.0, atol=0.6)
    np.testing.assert_allclose(fit.intercept_db, -40.0, atol=6.0)
    assert np.all(fit.rms_residual_db < 6.0)


def test_locate_recovers_a_point_from_its_own_model(sim):
    loc = LmsLocator.for_site(sim.site)
    p = np.array([[3.3, 7.1, sim.site.area.z_m]])
    ridx = np.arange(len(sim.site.receivers))
    rss = loc.fit.predict_dbm(p, ridx, 15.0)[0]
    np.testing.assert_allclose(loc.locate(ridx, rss, 15.0), p[0], atol=1e-3)
    # three receivers are enough, and the estimate stays inside the area
    est = loc.locate(ridx[:3], rss[:3] + 30.0, 15.0)
    assert 0.0 <= est[0] <= 12.0 and 0.0 <= est[1] <= 12.0
