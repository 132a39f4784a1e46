"""A free transmit power: the likelihood's MSE with the power offset profiled out.

The model's expected RSS is ``M_r(p) + P_tx + D(φ_r, θ_r) + δ`` with ``δ`` the
device's offset from its enrolled power ``P_tx`` (dB). For the residuals
``e_r = RSS_r − M_r(p) − P_tx − D`` of one candidate over ``h`` receivers

    MSE(δ) = (1/h) Σ_r (e_r − δ)² = var(e) + (ē − δ)²                       (dB²)

is minimised over ``|δ| ≤ Δ`` in closed form by ``δ* = clip(ē, −Δ, Δ)``
(:func:`best_power_mse_db2`). With a Gaussian prior ``δ ~ N(δ₀, s²)`` and
noise ``σ`` over ``n`` readings, the posterior mode is the precision-weighted
mean (:func:`profile_offset_db`). Used by the attacker model
(:mod:`radiopose.security.attacker`) and by the ``filter`` method's
re-entry proposals (:mod:`radiopose.filtering.particle`).
"""

from __future__ import annotations

import numpy as np

from radiopose.units import FloatArray


def best_power_offset_db(residual_db: FloatArray, power_range_db: float) -> FloatArray:
    """Optimal power offset ``δ* = clip(mean_r e_r, −Δ, Δ)`` (dB) of ``(n, h)`` residuals."""
    e = np.asarray(residual_db, dtype=np.float64)
    return np.clip(e.mean(axis=-1), -power_range_db, power_range_db)


def best_power_mse_db2(
    residual_db: FloatArray, power_range_db: float
) -> tuple[FloatArray, FloatArray]:
    """``min_{|δ|≤Δ} mean_r (e_r − δ)²`` and its ``δ*`` for ``(n, h)`` residuals.

    Returns
    -------
    mse_db2
        ``(n,)`` the minimum, dB².
    offset_db
        ``(n,)`` the minimiser ``δ*``, dB.
    """
    e = np.asarray(residual_db, dtype=np.float64)
    off = best_power_offset_db(e, power_range_db)
    d = e - off[..., None]
    return np.mean(d * d, axis=-1), off


def profile_offset_db(
    residual_db: FloatArray,
    n_readings: float,
    sigma_db: float,
    prior_db: float,
    prior_sd_db: float,
) -> tuple[FloatArray, FloatArray, float]:
    """The posterior of the offset per row of ``(n, h)`` residuals under a Gaussian prior.

    Each row's ``h`` residuals stand for ``n_readings`` readings in all (e.g. a
    window's median RSS over several packets), each with noise ``σ`` dB.

    Returns
    -------
    offset_db
        ``(n,)`` posterior mean ``(λ ē + λ₀ δ₀) / (λ + λ₀)``, ``λ = n_readings/σ²``,
        ``λ₀ = 1/s²``, dB.
    cost
        ``(n,)`` negative log-likelihood with the offset at that mean:
        ``(n_readings/h) Σ_r (e_r − δ̂)² / 2σ² + λ₀ (δ̂ − δ₀)² / 2`` (nats).
    precision
        ``λ``, 1/dB².
    """
    e = np.asarray(residual_db, dtype=np.float64)
    h = e.shape[-1]
    lam = n_readings / sigma_db**2
    lam0 = 1.0 / prior_sd_db**2
    off = (lam * e.mean(axis=-1) + lam0 * prior_db) / (lam + lam0)
    cost = 0.5 * (n_readings / h) * np.sum((e - off[..., None]) ** 2, axis=-1) / sigma_db**2
    return off, cost + 0.5 * lam0 * (off - prior_db) ** 2, lam
