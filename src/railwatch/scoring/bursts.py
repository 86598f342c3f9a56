"""A burst of rough track: a short oscillation, found and taken out of a whitened residual when
it is better explained as an oscillation than as a defect (``docs/nuisance-glr.md``).

A burst (the paper's stage 7; rough spots of track on a recording) is a sinusoid switched on for
a few samples, ``a cos(2π ν m) + b sin(2π ν m)`` on a span of ``L`` samples. A test for a box or a
spike fires on it: half a cycle of it looks like a box, its largest sample like a spike. This
module answers the composite null's first question, per series: is there a span better explained
by a short oscillation than by a box or a spike? It looks where the residual's energy peaks (a
burst is the most energetic thing in its window, or a defect is, and then the window is
anomalous anyway) and fits every atom whose span covers that sample, for every frequency of a
grid and every length (a 2 × 2 least-squares fit each, from cumulative sums over a segment of
the window). The best atom is taken out when its energy (the drop of the residual's sum of
squares, in noise variances) exceeds ``minimum`` and exceeds ``1 + ratio`` times what the best
box or spike that overlaps its span explains, plus ``margin``: a box or a spike stays, since a
box explains itself better than any oscillation (half a sine explains 81 % of a box's energy at
best) and a spike is a box of one sample. The share ``ratio`` is for large defects: a spike
that a resampler's anti-alias filter has spread rings at the filter's edge, and an oscillation
explains that ringing a few per cent better than a spike, many noise variances on a large one.

Everything is in samples and cycles per sample: a 5-20-sample atom at 100 Hz is 0.05-0.2 s,
the lengths the benchmark gives bursts and local deviations alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Burst:
    """The best atom of every series (B,): its energy in noise variances, first sample, length,
    frequency (cycles per sample), whether it is taken out, and the fitted atom (B, T), zero
    outside its span."""

    energy: F64
    start: NDArray[np.int64]
    length: NDArray[np.int64]
    freq: F64
    kept: NDArray[np.bool_]
    fit: F64


def frequency_grid(length: int, max_length: int, oversample: float) -> F64:
    """An atom's frequencies (cycles per sample) for a span of ``length`` samples: from one
    cycle per ``max_length`` samples (slower is a box) to the Nyquist frequency, ``oversample``
    per ``1 / length``, the resolution a span of that length has.

    >>> frequency_grid(5, 20, 1.0).round(2).tolist()
    [0.05, 0.25, 0.45]
    """
    return np.arange(1.0 / max_length, 0.5 + 1e-9, 1.0 / (oversample * length))


@dataclass(frozen=True)
class Atoms:
    """Every atom tried around a peak, on a segment of ``span`` samples whose sample ``centre``
    is the peak: cos and sin on each atom's span (span, A), each atom's length and first sample
    in the segment (A,), frequency (A,), and the inverse 2 × 2 Gram matrix of [cos, sin] on its
    span (three entries, (A,) each)."""

    span: int
    centre: int
    cos: F64
    sin: F64
    length: NDArray[np.int64]
    first: NDArray[np.int64]
    freq: F64
    g11: F64
    g12: F64
    g22: F64

    @property
    def single(self) -> tuple[NDArray[np.float32], ...]:
        """cos, sin, g11, 2 g12 and g22 in single precision, for the search (made once)."""
        if "_single" not in self.__dict__:
            object.__setattr__(self, "_single", tuple(
                a.astype(np.float32) for a in (self.cos, self.sin, self.g11, 2 * self.g12,
                                               self.g22)))
        return self.__dict__["_single"]  # type: ignore[no-any-return]


@lru_cache(maxsize=8)
def atoms(lengths: tuple[int, ...], oversample: float) -> Atoms:
    """The atoms of every length and frequency (:func:`frequency_grid`) whose span covers the
    segment's centre; those whose Gram matrix is singular (the Nyquist frequency's sine is
    zero) left out."""
    longest = max(lengths)
    span, centre = 2 * longest - 1, longest - 1
    m = np.arange(span)[:, None]
    length, first, freq = (np.concatenate(a) for a in zip(*(
        (np.full(len(f) * n, n), np.tile(np.arange(centre - n + 1, centre + 1), len(f)),
         np.repeat(f, n))
        for n in lengths for f in [frequency_grid(n, longest, oversample)]), strict=True))
    inside = (m >= first) & (m < first + length)
    cos = np.cos(2 * np.pi * freq * m) * inside
    sin = np.sin(2 * np.pi * freq * m) * inside
    a, b, d = (cos * cos).sum(0), (sin * sin).sum(0), (cos * sin).sum(0)
    det = a * b - d * d
    ok = det > 1e-6 * a * b + 1e-12
    return Atoms(span, centre, cos[:, ok], sin[:, ok], length[ok], first[ok], freq[ok],
                 (b / det)[ok], (-d / det)[ok], (a / det)[ok])


def energy_peak(w: F64, length: int) -> NDArray[np.int64]:
    """Per series (B, T), the first sample of the ``length``-sample stretch of largest energy,
    plus half the length: the sample every atom is made to cover."""
    cs = np.concatenate([np.zeros((len(w), 1)), np.cumsum(w * w, axis=1)], axis=1)
    return np.argmax(cs[:, length:] - cs[:, :-length], axis=1) + length // 2


def best_burst(w: F64, lengths: tuple[int, ...], oversample: float, margin: float,
               minimum: float, ratio: float = 0.5, boxes: tuple[int, ...] | None = None
               ) -> Burst:
    """The best oscillation atom of every series of the whitened residual ``w`` (B, T) among
    those covering its :func:`energy_peak` (atoms of ``lengths`` samples), and whether it is
    taken out (module docstring) against a spike or a box of ``boxes`` samples (``lengths``
    if not given)."""
    n_series, n_steps = w.shape
    at = atoms(tuple(lengths), oversample)
    peak = energy_peak(w, min(lengths))
    padded = np.pad(w, ((0, 0), (at.centre, at.centre)))
    seg = padded[np.arange(n_series)[:, None], peak[:, None] + np.arange(at.span)[None, :]]
    cos32, sin32, g11, g12x2, g22 = at.single  # the search in single precision, the fit in double
    seg32 = seg.astype(np.float32)
    bc, bs = seg32 @ cos32, seg32 @ sin32  # (B, A)
    energy = g11 * bc * bc
    energy += g12x2 * bc * bs
    energy += g22 * bs * bs
    start = peak[:, None] - at.centre + at.first[None, :]  # (B, A): in the window
    edge = (peak < at.centre) | (peak > n_steps - at.span + at.centre)
    if edge.any():  # atoms that leave the window are not atoms of it
        out = (start[edge] < 0) | (start[edge] + at.length > n_steps)
        energy[edge] = np.where(out, -np.inf, energy[edge])
    best = np.argmax(energy, axis=1)
    rows = np.arange(n_series)
    first, length = start[rows, best], at.length[best]
    # the atom: least-squares coefficients on its span, laid back into the window
    c, s = at.cos[:, best].T, at.sin[:, best].T  # (B, span)
    bc1, bs1 = (seg * c).sum(axis=1), (seg * s).sum(axis=1)
    coef_c = at.g11[best] * bc1 + at.g12[best] * bs1
    coef_s = at.g12[best] * bc1 + at.g22[best] * bs1
    e = coef_c * bc1 + coef_s * bs1
    local = np.arange(at.span)[None, :]
    atom = coef_c[:, None] * c + coef_s[:, None] * s
    inside = np.isfinite(energy[rows, best])  # a window shorter than every atom has none
    defect = defect_energy(w, first, length, lengths if boxes is None else boxes)
    kept = inside & (e > minimum) & (e - margin > (1 + ratio) * defect)
    fit = np.zeros((n_series, n_steps + 2 * at.centre))
    fit[rows[:, None], peak[:, None] + local] = np.where(kept[:, None], atom, 0.0)
    return Burst(e, first, length, at.freq[best], kept, fit[:, at.centre:at.centre + n_steps])


def defect_energy(w: F64, start: NDArray[np.int64], length: NDArray[np.int64],
                  lengths: tuple[int, ...]) -> F64:
    """Per series, the most energy a spike or a box (``lengths``) that overlaps the span
    [start, start + length) explains: ``w_t²`` or ``(Σ w)² / L``. Only the samples a box over
    the span can reach are looked at."""
    n_series, n_steps = w.shape
    reach = max(lengths) - 1
    width = int(length.max()) + 2 * reach  # every box that overlaps the span lies in here
    origin = start - reach  # the band's first sample, in the window (may lie before it)
    pos = origin[:, None] + np.arange(width)[None, :]
    valid = (pos >= 0) & (pos < n_steps)
    band = np.where(valid, w[np.arange(n_series)[:, None], np.clip(pos, 0, n_steps - 1)], 0.0)
    local = np.arange(width)[None, :]
    inside = (local >= reach) & (local < reach + length[:, None])
    best = np.where(inside, band * band, 0.0).max(axis=1)
    cs = np.concatenate([np.zeros((n_series, 1)), np.cumsum(band, axis=1)], axis=1)
    vs = np.concatenate([np.zeros((n_series, 1)), np.cumsum(valid, axis=1)], axis=1)
    for box in (b for b in lengths if b <= n_steps):
        sums = cs[:, box:] - cs[:, :-box]  # boxes starting at 0 .. width - box of the band
        whole = (vs[:, box:] - vs[:, :-box]) == box  # inside the window
        s = local[:, :width - box + 1]
        overlaps = whole & (s < reach + length[:, None]) & (s + box > reach)
        best = np.maximum(best, np.where(overlaps, sums * sums / box, 0.0).max(axis=1))
    return best
