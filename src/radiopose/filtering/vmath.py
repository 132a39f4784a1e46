"""Branch-free ``exp``, ``log``, ``atan2`` and ``sin``/``cos`` for the filter's compiled loops.

numba calls the C library's ``exp``/``log``/``atan2``/``sin``/``cos`` one value at a time, so a
loop that uses them cannot be vectorised (SIMD); the filter's per-particle
likelihood spends most of its time in those calls (docs/performance.md,
"Fourth pass"). These versions are plain float64 arithmetic with selects
instead of branches (the rational approximations of Cephes, S. L. Moshier,
with its range reductions), so LLVM vectorises a loop over particles that
calls them, inlined, when the loop's function is compiled with
``error_model="numpy"`` (no division-by-zero checks).

Accuracy (checked by ``tests/test_filter_speed.py`` against :mod:`math` on
10⁵ random arguments and the edge cases): ``exp`` within 2 ulp on
``[-708, 709]`` (arguments below −708 give ``exp(−708)`` ≈ 3e-308 instead of a
smaller number or 0; above 709, ``exp(709)``), ``log`` within 2 ulp (absolute
≤ 2.3e-16 for arguments in ``[0.5, 2]``) for positive normal arguments,
``atan2`` within 2 ulp (absolute ≤ 5e-16 rad) for finite arguments, the
C library's values on the axes (at a signed zero argument it may return
``0``/``π`` where the C library returns ``±0``/``±π``; ``atan2(0, 0) = 0``),
``sincos`` within 2 ulp (absolute ≤ 2.3e-16; near the zeros of sin and cos
the absolute error is below 1e-30) for ``|x| < 2²⁹``, and ``(0, 1)`` exactly
at 0.
Their numbers differ from the C library's in the last bit for a fraction of
arguments, so results that use them are not bit-identical to those of
``math.exp`` and friends; no argument is NaN or infinite in the filter's use
(callers map those cases before calling).

No fast-math flags: the operations are IEEE float64 without contraction, so
the results are the same on every x86-64 machine and at every SIMD width.

numba's on-disk cache keys a compiled function by its own source file, not by
the modules it inlines: after editing this module, clear the cache of its
callers (``kernels.py``) or touch their file.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
from numba.core import types
from numba.extending import intrinsic


def _bitcast(source: Any, target: Any) -> Any:
    """A numba intrinsic reinterpreting a ``source`` scalar's bits as ``target``
    (an LLVM bitcast: no instruction, vectorises)."""

    def impl(typingctx, x):  # pragma: no cover - compiled
        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], context.get_value_type(target))

        return target(source), codegen

    return intrinsic(impl)


_bits: Any = _bitcast(types.float64, types.int64)
"""The IEEE-754 bits of a float64 as int64 (compiled code only)."""
_from_bits: Any = _bitcast(types.int64, types.float64)
"""The float64 with the given IEEE-754 bits (int64; compiled code only)."""


# exp: x = k ln2 + r, |r| <= ln2 / 2; exp(r) = 1 + 2 r P(r²) / (Q(r²) − r P(r²))
_LOG2E = 1.4426950408889634073599
_LN2_HI = 6.93145751953125e-1
_LN2_LO = 1.42860682030941723212e-6
_EP0 = 1.26177193074810590878e-4
_EP1 = 3.02994407707441961300e-2
_EP2 = 9.99999999999999999910e-1
_EQ0 = 3.00198505138664455042e-6
_EQ1 = 2.52448340349684104192e-3
_EQ2 = 2.27265548208155028766e-1
_EQ3 = 2.00000000000000000009e0
_EXP_MIN = -708.0
_EXP_MAX = 709.0


@numba.njit(cache=True, inline="always", error_model="numpy")
def vexp(x):  # pragma: no cover - compiled
    """``exp(x)`` (within 2 ulp), ``x`` clamped to ``[-708, 709]``; branch-free."""
    x = min(max(x, _EXP_MIN), _EXP_MAX)
    fk = math.floor(_LOG2E * x + 0.5)
    r = x - fk * _LN2_HI
    r = r - fk * _LN2_LO
    rr = r * r
    px = r * ((_EP0 * rr + _EP1) * rr + _EP2)
    qx = ((_EQ0 * rr + _EQ1) * rr + _EQ2) * rr + _EQ3
    y = 1.0 + 2.0 * (px / (qx - px))
    return y * _from_bits((np.int64(fk) + 1023) << 52)  # × 2^k, k in [-1022, 1023]


# log: x = m 2^e, m in [√½, √2); log(1 + z) = z − z²/2 + z³ P(z) / Q(z), z = m − 1
_SQRT_HALF = 0.70710678118654752440
_LP0 = 1.01875663804580931796e-4
_LP1 = 4.97494994976747001425e-1
_LP2 = 4.70579119878881725854e0
_LP3 = 1.44989225341610930846e1
_LP4 = 1.79368678507819816313e1
_LP5 = 7.70838733755885391666e0
_LQ0 = 1.12873587189167450590e1
_LQ1 = 4.52279145837532221105e1
_LQ2 = 8.29875266912776603211e1
_LQ3 = 7.11544750618563894466e1
_LQ4 = 2.31251620126765340583e1
_LN2_LOG_HI = 0.693359375
_LN2_LOG_LO = -2.121944400546905827679e-4
_MANTISSA = 0x000FFFFFFFFFFFFF
_HALF_EXPONENT = 0x3FE0000000000000


@numba.njit(cache=True, inline="always", error_model="numpy")
def vlog(x):  # pragma: no cover - compiled
    """``log(x)`` (within 2 ulp) for a positive normal ``x``; branch-free."""
    b = _bits(x)
    e = ((b >> 52) & 0x7FF) - 1022
    m = _from_bits((b & _MANTISSA) | _HALF_EXPONENT)  # x = m 2^e, m in [0.5, 1)
    low = m < _SQRT_HALF
    e = e - 1 if low else e
    z = (m + m - 1.0) if low else (m - 1.0)
    fe = float(e)
    zz = z * z
    p = ((((_LP0 * z + _LP1) * z + _LP2) * z + _LP3) * z + _LP4) * z + _LP5
    q = ((((z + _LQ0) * z + _LQ1) * z + _LQ2) * z + _LQ3) * z + _LQ4
    y = z * (zz * p / q)
    y = y + fe * _LN2_LOG_LO
    y = y - 0.5 * zz
    return (z + y) + fe * _LN2_LOG_HI


# atan on [0, ∞): reduced to |t| <= tan(π/8) by t = −1/x (x > tan 3π/8) or
# (x − 1)/(x + 1) (x > 0.66); atan t = t + t³ P(t²) / Q(t²)
_T3P8 = 2.41421356237309504880
_MOREBITS = 6.123233995736765886130e-17
_AP0 = -8.750608600031904122785e-1
_AP1 = -1.615753718733365076637e1
_AP2 = -7.500855792314704667340e1
_AP3 = -1.228866684490136173410e2
_AP4 = -6.485021904942025371773e1
_AQ0 = 2.485846490142306297962e1
_AQ1 = 1.650270098316988542046e2
_AQ2 = 4.328810604912902668951e2
_AQ3 = 4.853903996359136964868e2
_AQ4 = 1.945506571482613964425e2


@numba.njit(cache=True, inline="always", error_model="numpy")
def _atan_nonneg(x):  # pragma: no cover - compiled
    """``atan(x)`` for ``x >= 0`` (``+inf`` gives π/2); branch-free."""
    big = x > _T3P8
    mid = x > 0.66
    t = -1.0 / x if big else ((x - 1.0) / (x + 1.0) if mid else x)
    y0 = 0.5 * math.pi if big else (0.25 * math.pi if mid else 0.0)
    extra = _MOREBITS if big else (0.5 * _MOREBITS if mid else 0.0)
    z = t * t
    p = (((_AP0 * z + _AP1) * z + _AP2) * z + _AP3) * z + _AP4
    q = ((((z + _AQ0) * z + _AQ1) * z + _AQ2) * z + _AQ3) * z + _AQ4
    return y0 + ((t * (z * p / q) + t) + extra)


@numba.njit(cache=True, inline="always", error_model="numpy")
def vatan2(y, x):  # pragma: no cover - compiled
    """``atan2(y, x)`` radians in ``[-π, π]`` (within 2 ulp) for finite ``y, x``
    (``atan2(0, 0) = 0``); branch-free."""
    ax = abs(x)
    ay = abs(y)
    t = _atan_nonneg(ay / ax) if ax > 0.0 else (0.5 * math.pi if ay > 0.0 else 0.0)
    t = math.pi - t if x < 0.0 else t
    return -t if y < 0.0 else t


# sin and cos: x = j π/4 + z (j even, |z| <= π/4, π/4 in three parts);
# sin z = z + z³ S(z²), cos z = 1 − z²/2 + z⁴ C(z²); the octant picks which and the signs
_FOUR_OVER_PI = 4.0 / math.pi
_PI4_A = 7.85398125648498535156e-1
_PI4_B = 3.77489470793079817668e-8
_PI4_C = 2.69515142907905952645e-15
_S0 = 1.58962301576546568060e-10
_S1 = -2.50507477628578072866e-8
_S2 = 2.75573136213857245213e-6
_S3 = -1.98412698295895385996e-4
_S4 = 8.33333333332211858878e-3
_S5 = -1.66666666666666307295e-1
_C0 = -1.13585365213876817300e-11
_C1 = 2.08757008419747316778e-9
_C2 = -2.75573141792967388112e-7
_C3 = 2.48015872888517045348e-5
_C4 = -1.38888888888730564116e-3
_C5 = 4.16666666666665929218e-2


@numba.njit(cache=True, inline="always", error_model="numpy")
def vsincos(x):  # pragma: no cover - compiled
    """``(sin x, cos x)`` (each within 2 ulp, absolute ≤ 2.3e-16) for
    ``|x| < 2²⁹``; branch-free. ``vsincos(0) = (0, 1)`` exactly."""
    neg = x < 0.0
    ax = -x if neg else x
    j = np.int64(ax * _FOUR_OVER_PI)
    odd = (j & 1) == 1
    j = j + 1 if odd else j
    y = float(j)
    j = j & 7
    z = ((ax - y * _PI4_A) - y * _PI4_B) - y * _PI4_C
    flip = j > 3
    j = j - 4 if flip else j
    sin_neg = neg != flip
    cos_neg = flip != (j > 1)
    zz = z * z
    c = (
        1.0
        - 0.5 * zz
        + zz * zz * (((((_C0 * zz + _C1) * zz + _C2) * zz + _C3) * zz + _C4) * zz + _C5)
    )
    s = z + z * zz * (((((_S0 * zz + _S1) * zz + _S2) * zz + _S3) * zz + _S4) * zz + _S5)
    swap = j == 1 or j == 2
    sin_x = c if swap else s
    cos_x = s if swap else c
    return (-sin_x if sin_neg else sin_x), (-cos_x if cos_neg else cos_x)
