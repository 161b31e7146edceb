"""Wind: Dryden turbulence (MIL-F-8785C low-altitude form), discretised exactly (docs/design.md §3).

The gust is a stationary Gaussian process given by its power spectral density. In the Dryden
form (MIL-F-8785C §3.7.2.1, Table IV; MIL-HDBK-1797 Appendix A) the one-sided temporal PSDs in
(m/s)²/(rad/s) of a vehicle passing through a frozen turbulence field at speed V are

    Φ_u(ω) = σ_u² (2 L_u/(π V)) / (1 + (L_u ω/V)²),
    Φ_v(ω) = σ_v² (L_v/(π V)) (1 + 3 (L_v ω/V)²) / (1 + (L_v ω/V)²)²   (Φ_w alike, with w),

each integrating to σ² over ω ∈ [0, ∞). Unit-intensity white noise η (E[η(t)η(s)] = δ(t − s))
through ``H_u(s) = σ_u √(2a_u) / (s + a_u)`` and ``H_v(s) = σ_v √a_v (√3 s + a_v) / (s + a_v)²``
with ``a = V/L`` (|H|² = π Φ) makes exactly these spectra. The low-altitude model (MIL-F-8785C
§3.7.2.3, altitude h in ft, 10 ft ≤ h ≤ 1000 ft) sets

    L_w = h,  L_u = L_v = h / (0.177 + 0.000823 h)^1.2,
    σ_w = 0.1 W20,  σ_u = σ_v = σ_w / (0.177 + 0.000823 h)^0.4,

with W20 the wind speed at 20 ft (6.1 m): 15, 30 and 45 knots for light, moderate and severe
turbulence (MIL-F-8785C Figure 10). Below 10 ft the 10 ft values are used (L_w = h → 0 at the
ground). The axes are u along the steady wind's horizontal direction (north without one), v
horizontal to its right, w down (N is NED, docs/design.md §2).

Discretisation: the filter states (5: one for u, two each for v and w) are advanced over the
update period T with the exact transition Φ = e^{AT} and the exact covariance of the driving
noise ``Q_d = ∫₀ᵀ e^{Aτ} B Bᵀ e^{Aᵀτ} dτ`` (closed forms below), and start from the stationary
covariance P∞. So the sampled gust has exactly the Dryden autocovariance at the sample
instants; its PSD is the Dryden PSD folded at the sampling rate (aliasing, no other error).
Between samples the simulator holds the wind (zero-order hold). The kernels take the normals as
input and draw nothing (layer 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.types import FloatArray

FOOT = 0.3048
"""One foot in m."""

KNOT = 1852.0 / 3600.0
"""One knot in m/s."""

W20_MPS = {"light": 15.0 * KNOT, "moderate": 30.0 * KNOT, "severe": 45.0 * KNOT}
"""W20, the wind speed at 20 ft, of the standard's turbulence intensities (MIL-F-8785C
Figure 10), m/s."""

GUST_STATES = 5
"""Filter states of the three Dryden filters: u (1), v (2), w (2)."""


def dryden_low_altitude(altitude_m: float, w20_mps: float) -> tuple[FloatArray, FloatArray]:
    """Intensities and scale lengths of the low-altitude model (MIL-F-8785C §3.7.2.3).

    Args:
        altitude_m: Height above ground h in m (below 10 ft = 3.048 m, the 10 ft values).
        w20_mps: Wind speed at 20 ft (6.1 m), W20, m/s (≥ 0).

    Returns:
        ``(sigma (3,) m/s, length (3,) m)`` along the turbulence axes (u, v, w).
    """
    h_ft = max(float(altitude_m), 10.0 * FOOT) / FOOT
    d = 0.177 + 0.000823 * h_ft
    sigma_w = 0.1 * float(w20_mps)
    sigma_uv = sigma_w / d**0.4
    length_uv = h_ft / d**1.2 * FOOT
    sigma = np.array([sigma_uv, sigma_uv, sigma_w])
    length = np.array([length_uv, length_uv, h_ft * FOOT])
    return sigma, length


def dryden_psd(
    freq_hz: ArrayLike, sigma: ArrayLike, length: ArrayLike, airspeed_mps: float
) -> FloatArray:
    """One-sided Dryden PSDs of the gust components in (m/s)²/Hz (module docstring).

    ``S(f) = 2π Φ(2π f)``, so ``∫₀^∞ S df = σ²``.

    Args:
        freq_hz: (n,) frequencies f ≥ 0 in Hz.
        sigma: (3,) intensities (u, v, w) in m/s. length: (3,) scale lengths in m.
        airspeed_mps: V, the speed of the air past the vehicle, m/s (> 0).

    Returns:
        (3, n) PSD of u, v and w.
    """
    f = np.asarray(freq_hz, dtype=float)
    sig = np.asarray(sigma, dtype=float)
    ell = np.asarray(length, dtype=float)
    x2 = (2.0 * math.pi * f[None, :] * ell[:, None] / airspeed_mps) ** 2
    scale = (sig**2 * ell / airspeed_mps)[:, None]
    out = 2.0 * scale * (1.0 + 3.0 * x2) / (1.0 + x2) ** 2
    out[0] = 4.0 * scale[0] / (1.0 + x2[0])
    return out


@dataclass(frozen=True)
class DrydenFilter:
    """The exact discrete-time Dryden shaping filters of one setting (module docstring).

    ``x_{k+1} = Φ x_k + L_d z_k`` with ``z_k ~ N(0, I₅)``, gust ``g_k = C x_k`` (m/s, axes u, v,
    w), ``x_0 = L∞ z`` with ``L∞ L∞ᵀ = P∞``.

    Attributes:
        phi: (5, 5) transition Φ over the period. chol: (5, 5) lower ``L_d`` of ``Q_d``.
        stationary: (5, 5) lower ``L∞`` of the stationary covariance.
        output: (3, 5) C, filter state to gust along (u, v, w).
        sigma: (3,) m/s. length: (3,) m. airspeed_mps: V. period_s: T.
    """

    phi: FloatArray
    chol: FloatArray
    stationary: FloatArray
    output: FloatArray
    sigma: FloatArray
    length: FloatArray
    airspeed_mps: float
    period_s: float


def _exp_moments(a: float, t: float) -> tuple[float, float, float]:
    """``I_n = ∫₀ᵗ τⁿ e^{−2aτ} dτ`` for n = 0, 1, 2 without cancellation.

    For ``x = 2at < 1`` the series ``I_n = t^{n+1} Σ_k (−x)^k / (k! (n+1+k))`` (25 terms:
    error below 1e-25 relative), else the closed form ``n!/(2a)^{n+1} (1 − e^{−x} Σ_{k≤n}
    x^k/k!)``.
    """
    x = 2.0 * a * t
    if x < 1.0:
        out = []
        for n in range(3):
            total, term = 0.0, 1.0
            for k in range(25):
                total += term / (n + 1 + k)
                term *= -x / (k + 1)
            out.append(t ** (n + 1) * total)
        return out[0], out[1], out[2]
    e = math.exp(-x)
    i0 = (1.0 - e) / (2.0 * a)
    i1 = (1.0 - e * (1.0 + x)) / (2.0 * a) ** 2
    i2 = 2.0 * (1.0 - e * (1.0 + x + 0.5 * x * x)) / (2.0 * a) ** 3
    return i0, i1, i2


def dryden_filter(
    sigma: ArrayLike, length: ArrayLike, airspeed_mps: float, period_s: float
) -> DrydenFilter:
    """The exact discretisation of the Dryden filters over ``period_s`` (module docstring).

    First order (u), ``ẋ = −a x + η``: ``Φ = e^{−aT}``, ``Q_d = I_0``, ``P∞ = 1/(2a)``.
    Second order (v, w), ``ẋ₁ = x₂, ẋ₂ = −a² x₁ − 2a x₂ + η``: ``e^{AT} = e^{−aT} [[1 + aT,
    T], [−a²T, 1 − aT]]``, ``e^{Aτ}B = e^{−aτ} (τ, 1 − aτ)``, so ``Q_d = [[I_2, I_1 − a I_2],
    [·, I_0 − 2a I_1 + a² I_2]]`` and ``P∞ = diag(1/(4a³), 1/(4a))``.

    Args:
        sigma: (3,) intensities (u, v, w), m/s. length: (3,) scale lengths, m (> 0).
        airspeed_mps: V in m/s (> 0). period_s: Update period T in s (> 0).

    Returns:
        The filter.
    """
    sig = np.asarray(sigma, dtype=float).reshape(3)
    ell = np.asarray(length, dtype=float).reshape(3)
    v, t = float(airspeed_mps), float(period_s)
    phi, chol, stat = np.zeros((5, 5)), np.zeros((5, 5)), np.zeros((5, 5))
    out = np.zeros((3, 5))
    a = v / ell[0]
    i0, _, _ = _exp_moments(a, t)
    phi[0, 0], chol[0, 0], stat[0, 0] = math.exp(-a * t), math.sqrt(i0), math.sqrt(0.5 / a)
    out[0, 0] = sig[0] * math.sqrt(2.0 * a)
    for axis, j in ((1, 1), (2, 3)):
        a = v / ell[axis]
        e = math.exp(-a * t)
        phi[j : j + 2, j : j + 2] = e * np.array([[1.0 + a * t, t], [-a * a * t, 1.0 - a * t]])
        i0, i1, i2 = _exp_moments(a, t)
        q11, q12, q22 = i2, i1 - a * i2, i0 - 2.0 * a * i1 + a * a * i2
        l11 = math.sqrt(q11)
        l21 = q12 / l11
        chol[j, j], chol[j + 1, j], chol[j + 1, j + 1] = l11, l21, math.sqrt(q22 - l21 * l21)
        stat[j, j], stat[j + 1, j + 1] = math.sqrt(0.25 / a**3), math.sqrt(0.25 / a)
        gain = sig[axis] * math.sqrt(a)
        out[axis, j], out[axis, j + 1] = gain * a, gain * math.sqrt(3.0)
    return DrydenFilter(phi, chol, stat, out, sig, ell, v, t)


def gust_axes(steady_n: ArrayLike) -> FloatArray:
    """(3, 3) columns u, v, w of the turbulence axes in N: u along the steady wind's
    horizontal direction (north when it has none), v 90° to its right, w down."""
    w = np.asarray(steady_n, dtype=float).reshape(3)
    psi = math.atan2(w[1], w[0]) if w[0] != 0.0 or w[1] != 0.0 else 0.0
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@inline_kernel
def dryden_advance(
    x: FloatArray, z: FloatArray, phi: FloatArray, chol: FloatArray, y: FloatArray
) -> None:
    """``x ← Φ x + L_d z`` for one filter state x (5,) in place, normals z (5,); y (5,) is
    scratch, passed in so that a loop over lanes allocates nothing per lane."""
    for r in range(GUST_STATES):
        acc = 0.0
        for c in range(GUST_STATES):
            acc += phi[r, c] * x[c] + chol[r, c] * z[c]
        y[r] = acc
    x[:] = y


@inline_kernel
def wind_output(x: FloatArray, out_map: FloatArray, steady: FloatArray, out: FloatArray) -> None:
    """``out = steady + M x``: the wind (3,) from a filter state x (5,), M (3, 5)."""
    for r in range(3):
        acc = steady[r]
        for c in range(GUST_STATES):
            acc += out_map[r, c] * x[c]
        out[r] = acc


@kernel
def dryden_series(
    x: FloatArray,
    noise: FloatArray,
    phi: FloatArray,
    chol: FloatArray,
    out_map: FloatArray,
    out: FloatArray,
) -> None:
    """n gust samples of one filter: ``out[k] = M x_k`` then ``x ← Φ x + L_d z_k``.

    Args:
        x: (5,) filter state, advanced in place. noise: (n, 5) standard normals.
        phi, chol: (5, 5) of :class:`DrydenFilter`. out_map: (3, 5) M (e.g. its ``output``).
        out: (n, 3) gust samples, m/s.
    """
    zero, y = np.zeros(3), np.empty(GUST_STATES)
    for k in range(noise.shape[0]):
        wind_output(x, out_map, zero, out[k])
        dryden_advance(x, noise[k], phi, chol, y)


@kernel
def dryden_step_lanes(
    lanes: np.ndarray,
    cursor: np.ndarray,
    noise: FloatArray,
    states: FloatArray,
    phi: FloatArray,
    chol: FloatArray,
    out_map: FloatArray,
    steady: FloatArray,
    scale: FloatArray,
    wind: FloatArray,
) -> None:
    """Advance the filter of each lane in ``lanes`` one period and write its wind.

    Args:
        lanes: (k,) lane indices. cursor: (B,) next unused row of each lane's ``noise``.
        noise: (B, n, 5) pre-drawn normals. states: (B, 5) filter states, in place.
        phi, chol: (5, 5) of :class:`DrydenFilter`. out_map: (3, 5) filter state to the gust
            in N (turbulence axes times C). steady: (3,) steady wind in N, m/s.
        scale: (B,) factor on each lane's whole wind (domain randomisation; ones otherwise).
        wind: (B, 3) wind in N, m/s, written for the lanes: ``scale · (steady + M x)``.
    """
    y = np.empty(GUST_STATES)
    for i in lanes:
        dryden_advance(states[i], noise[i, cursor[i]], phi, chol, y)
        cursor[i] += 1
        wind_output(states[i], out_map, steady, wind[i])
        for r in range(3):
            wind[i, r] *= scale[i]
