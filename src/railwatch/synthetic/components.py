"""Signal components of the synthetic benchmark, one small vectorised function each.

Every function takes the time grid ``t`` of shape (T,) in seconds and per-instance, per-channel
parameters of shape (n, C) in physical units, and returns an array of shape (n, T, C) in float64.
Nothing here draws random numbers: sampling lives in :mod:`railwatch.synthetic.stages`.

>>> import numpy as np
>>> t = np.arange(4) / 4.0
>>> one = np.ones((1, 1))
>>> np.round(sinusoid(t, f=one, amp=one), 6)[0, :, 0].tolist()
[0.0, 1.0, 0.0, -1.0]
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def _grid(t: Array) -> Array:
    """The time grid as (1, T, 1), ready to broadcast against (n, 1, C) parameters."""
    return np.asarray(t, dtype=np.float64)[None, :, None]


def _p(x: Array) -> Array:
    """Per-instance, per-channel parameters (n, C) as (n, 1, C)."""
    return np.asarray(x, dtype=np.float64)[:, None, :]


def sinusoid(
    t: Array,
    f: Array,
    amp: Array,
    phi: Array | None = None,
    t_change: Array | None = None,
    k_f: Array | None = None,
    k_a: Array | None = None,
) -> Array:
    """Base sinusoid, optionally with a phase-continuous speed change (Stages 1-3).

    Before ``t_change``: ``A sin(2π f t + φ)``; from ``t_change`` on:
    ``k_A A sin(2π k_f f (t − t_c) + 2π f t_c + φ)`` (the paper's Stage-2 and Stage-3 equations).
    With ``t_change=None`` the signal is the Stage-1 sinusoid throughout.
    """
    tt = _grid(t)
    phase = 0.0 if phi is None else _p(phi)
    omega = 2 * np.pi * _p(f)
    if t_change is None:
        return _p(amp) * np.sin(omega * tt + phase)
    if k_f is None or k_a is None:
        raise ValueError("a speed change needs t_change, k_f and k_a together")
    tc = _p(t_change)
    before = tt < tc
    # One sine over both branches: the argument and amplitude switch at t_change.
    arg = np.where(before, omega * tt, _p(k_f) * omega * (tt - tc) + omega * tc)
    arg += phase
    np.sin(arg, out=arg)
    arg *= np.where(before, _p(amp), _p(k_a) * _p(amp))
    return arg


def noise_std(
    t: Array, sigma: Array, d_sigma: Array | None = None, t_noisechange: Array | None = None
) -> Array:
    """Per-sample noise standard deviation: σ, or σ + Δσ from ``t_noisechange`` on (Stage 4).

    The Stage-4 step replaces the constant noise: the total std is σ before and σ + Δσ after.
    """
    tt = _grid(t)
    base = np.broadcast_to(_p(sigma), (sigma.shape[0], tt.shape[1], sigma.shape[1]))
    if d_sigma is None or t_noisechange is None:
        return np.array(base)
    return np.where(tt < _p(t_noisechange), base, _p(sigma) + _p(d_sigma))


def hf_burst(
    t: Array, t_start: Array, duration: Array, psi: Array, alpha: Array, f_hf: Array
) -> Array:
    """High-frequency burst ``α sin(2π f_HF t + ψ)`` on the closed interval [t_HF, t_HF + Δt_HF].

    Absolute time t, rectangular on/off, zero outside its support (Stage 7).
    """
    tt = _grid(t)
    start = _p(t_start)
    on = (tt >= start) & (tt <= start + _p(duration))
    arg = 2 * np.pi * _p(f_hf) * tt + _p(psi)
    # The sine is evaluated only on the burst's support (about a tenth of the window).
    out = np.sin(arg, out=np.zeros_like(arg), where=on)
    out *= _p(alpha)
    return out


#: At most floor(3 ω_max / T_min) + 1 = 4 impulses overlap at one instant.
_MAX_OVERLAP = 4


def impulses(t: Array, omega: Array, period: Array, beta: Array, duration: float) -> Array:
    """Periodic one-sided truncated Gaussian impulses (Stage 8).

    ``Σ_{k=0}^{K−1} I(t − kT)`` with ``I(τ) = β exp(−(τ/ω)²)`` for ``0 ≤ τ ≤ 3ω``, else 0, the first
    impulse at t = 0 and ``K = floor(duration / T)``; overlapping impulses add.

    At any instant only the impulses ``k = floor(t/T) − j`` for a few ``j`` can be non-zero
    (3ω ≤ 0.3 s and T ≥ 0.1 s), so the sum runs over ``j`` instead of all K, keeping memory at
    a few (n, T, C) arrays.
    """
    tt = _grid(t)
    w, per, b = _p(omega), _p(period), _p(beta)
    n_impulses = np.floor(duration / per)
    k0 = np.floor(tt / per)  # the latest impulse started at t ...
    k0 += tt - (k0 + 1) * per >= 0  # ... unless floor() rounded t/T just below an integer
    out = np.zeros(np.broadcast_shapes(tt.shape, per.shape))
    for j in range(_MAX_OVERLAP):  # impulse k = k0 − j, started j periods before impulse k0
        k = k0 - j
        tau = tt - k * per  # literally t − kT, so that supports match the formula's edges
        on = (tau >= 0) & (tau <= 3 * w) & (k >= 0) & (k < n_impulses)
        if not on.any():
            break
        r = np.square(tau / w)
        np.negative(r, out=r)
        out += np.exp(r, out=np.zeros_like(r), where=on)
    out *= b
    return out


def span_mask(t: Array, start: Array, duration: Array) -> NDArray[np.bool_]:
    """(n, T) boolean mask of ``start ≤ t_n < start + duration`` for per-instance spans (n,)."""
    tt = np.asarray(t, dtype=np.float64)[None, :]
    s = np.asarray(start, dtype=np.float64)[:, None]
    e = s + np.asarray(duration, dtype=np.float64)[:, None]
    # A relative guard so that spans given on another sampling grid (spikes are defined on the
    # 100 Hz reference grid) select the same instants whatever fs is.
    eps = 1e-9
    return (tt >= s - eps) & (tt < e - eps)
