"""The GLR scan for spikes and boxes, shared by the oracle and the matched filter.

Both test a whitened, (approximately) N(0, 1) residual for the benchmark's two anomaly kinds
(``docs/benchmark.md``): a one-sample spike and a constant box of 5–20 samples, each
with unknown amplitude and sign. For a hypothesis ``h`` with template ``h`` the generalised
likelihood-ratio statistic is ``z = |<g, h>| / ||h||`` (the square root of ``2 log LR``), which is
|N(0, 1)| under the null for every hypothesis.

Two families of hypotheses are tested: the spike (one position per sample) and the box (every
length 5–20 at every start). Their maxima are not comparable as they stand: the largest of ~200
independent one-sample statistics and the largest of ~3,000 overlapping box statistics have
different null distributions (taking the plain maximum of all ``z`` lets the boxes' many tries
swamp the spikes). We put them on one scale by the family-wise tail probability under pure
N(0, 1) noise,

    p_f(z) = 1 − (1 − q(z))^m_f,    q(z) = 2 Φ̄(z)   (Šidák form),

where ``m_f`` is the *effective* number of independent tests of family ``f`` in a window, fitted
once by Monte Carlo on N(0, 1) windows (:func:`effective_counts`) so that ``p_f`` is exact at the
null's ``1 − alpha`` quantile of the family's window maximum (about ``T`` for spikes, about 480
for the 5–20 boxes at ``T = 200``). Every statistic is reported as ``−log10 p_f``; a (t, c) score
is the largest over the families, each box statistic being attributed to every sample the box
covers (:func:`covering_max`), so that localisation lands inside the anomaly.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.special import log_ndtr, ndtri_exp

FloatArray = NDArray[np.floating]

LOG10 = float(np.log(10.0))


Family = tuple[int, ...]  # box lengths (samples) tested together; (1,) is the spike


def families(min_box: int, max_box: int) -> tuple[Family, ...]:
    """The two hypothesis families: a spike, and boxes of ``min_box .. max_box`` samples.

    >>> families(5, 7)
    ((1,), (5, 6, 7))
    """
    return (1,), tuple(range(min_box, max_box + 1))


def cumulative(g: FloatArray) -> FloatArray:
    """``g`` (N, T, C) summed along time from a leading zero: (N, T + 1, C), float64."""
    n, _, c = g.shape
    return np.concatenate([np.zeros((n, 1, c)), np.cumsum(g, axis=1, dtype=np.float64)], axis=1)


def box_sums(g: FloatArray, length: int, cs: FloatArray | None = None) -> FloatArray:
    """Sums of ``g`` (N, T, C) over every box of ``length`` samples: (N, T − length + 1, C).

    Entry ``s`` is ``g[:, s:s + length].sum(axis=1)``, a difference of one cumulative sum
    (float64); pass ``cs = cumulative(g)`` to reuse it over several lengths.

    >>> box_sums(np.arange(5.0).reshape(1, 5, 1), 2)[0, :, 0]
    array([1., 3., 5., 7.])
    """
    cs = cumulative(g) if cs is None else cs
    return cs[:, length:] - cs[:, :-length]  # (N, T − L + 1, C)


def covering_max(stat: FloatArray, length: int) -> FloatArray:
    """Attribute box statistics to the samples they cover.

    ``stat`` (N, S, C) holds one value per box start ``s`` (``S = T − length + 1``); the result
    (N, T, C) holds at ``t`` the largest value over the boxes that cover ``t``
    (starts ``max(0, t − L + 1) .. min(t, S − 1)``). One length of :func:`covering_family_max`.

    >>> covering_max(np.array([[[1.0], [5.0], [2.0]]]), 2)[0, :, 0]
    array([1., 5., 5., 2.])
    """
    return covering_family_max({length: stat}, stat.shape[1] + length - 1)


def covering_family_max(stats: Mapping[int, FloatArray], n_steps: int) -> FloatArray:
    """The largest box statistic of several lengths covering each sample: (N, T, C).

    ``stats[L]`` (N, T − L + 1, C) holds the statistic of the box of ``L`` samples at each start
    ``s``; the box covers ``s .. s + L − 1``. Grouped by the offset ``k = t − s`` of a sample
    in its box: the boxes of every length ``L > k`` (a running maximum over the lengths, from
    the longest down) are shifted by ``k`` onto the samples. ``max L`` shifted maxima in all,
    two to three times faster than a running-maximum filter per length
    (docs/notes/2026-12-05-detect-speed.md). ``stats`` holds one length at least.
    """
    first = next(iter(stats.values()))
    shape = (first.shape[0], n_steps, first.shape[2])
    best = np.full(shape, -np.inf)
    longer = np.full(shape, -np.inf)  # at offset k: the boxes of every length L > k, by start
    for k in range(max(stats) - 1, -1, -1):
        z = stats.get(k + 1)
        if z is not None:
            np.maximum(longer[:, :z.shape[1]], z, out=longer[:, :z.shape[1]])
        np.maximum(best[:, k:], longer[:, :n_steps - k], out=best[:, k:])
    return best


def _covering(stats: Mapping[int, FloatArray], shape: tuple[int, ...]) -> FloatArray:
    """:func:`covering_family_max`, or all ``-inf`` of ``shape`` when no length fits."""
    return covering_family_max(stats, shape[1]) if stats else np.full(shape, -np.inf)


def log10_familywise_p(z: FloatArray, m: float) -> FloatArray:
    """``log10`` of the family-wise p-value ``1 − (1 − 2Φ̄(z))^m`` of a |N(0,1)| statistic ``z``.

    Stable for huge ``z`` (a spike of 40 noise standard deviations): below ``q = 1e-8`` it uses
    ``log m + log q``, the same quantity to within ``m q``.

    >>> float(np.round(log10_familywise_p(np.array([1.959964]), 1.0)[0], 4))
    -1.301
    """
    logq = np.log(2.0) + log_ndtr(-np.abs(z).astype(np.float64))  # log of the two-sided tail
    q = np.minimum(np.exp(logq), 1.0 - 1e-15)
    with np.errstate(divide="ignore"):
        exact = np.log(-np.expm1(m * np.log1p(-q)))
    tiny = logq < np.log(1e-8)
    return np.where(tiny, np.log(m) + logq, exact) / LOG10


def family_max(g: FloatArray, family: Family, norms: Sequence[FloatArray | float]) -> FloatArray:
    """Largest GLR statistic of ``family`` covering each sample: (N, T, C).

    ``g`` (N, T, C) is the residual correlated with the hypothesis' shape in the whitened domain
    (the whitened residual itself when the noise is white); the statistic of a box of ``L``
    samples starting at ``s`` is ``|sum g[s:s+L]| / norms[i]`` (``L = family[i]``), with
    ``norms[i]`` a scalar or broadcastable to (N, 1, C); it is |N(0,1)| under the null. Lengths
    longer than the window are skipped (all ``-inf`` if none fits). Box sums are differences of
    one cumulative sum (float64).
    """
    n_steps = g.shape[1]
    cs = cumulative(g)
    stats = {length: np.abs(box_sums(g, length, cs)) / norm  # (N, T − L + 1, C)
             for length, norm in zip(family, norms, strict=True) if length <= n_steps}
    return _covering(stats, g.shape)


def effective_counts(
    n_steps: int, fams: Sequence[Family], n_windows: int, alpha: float, seed: int
) -> NDArray[np.float64]:
    """Effective number of independent positions ``m_f`` of each family, by Monte Carlo.

    Simulates ``n_windows`` N(0, 1) windows of ``n_steps`` samples (seeded, so deterministic), takes
    each family's window maximum ``Z_f`` (over positions and lengths) and solves
    ``1 − (1 − q(z_α))^m = α`` at the empirical ``1 − α`` quantile ``z_α`` of ``Z_f``.
    Returns (len(fams),); a family with no length fitting in the window gets ``nan``.
    """
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal((n_windows, n_steps, 1))
    out = np.full(len(fams), np.nan)
    for i, fam in enumerate(fams):
        if min(fam) > n_steps:
            continue
        zmax = np.max([np.abs(box_sums(noise, L)).max(axis=(1, 2)) / np.sqrt(L)
                       for L in fam if L <= n_steps], axis=0)  # (n_windows,)
        out[i] = count_at(zmax, alpha)
    return out


def count_at(zmax: NDArray[np.float64], alpha: float) -> float:
    """The ``m`` that solves ``1 − (1 − q(z_α))^m = α`` at the ``1 − α`` quantile ``z_α`` of
    window maxima ``zmax`` simulated under N(0, 1) noise."""
    q = 2.0 * np.exp(log_ndtr(-np.quantile(zmax, 1.0 - alpha)))
    return float(np.log1p(-alpha) / np.log1p(-q))


def scale_counts(
    counts: NDArray[np.float64], fams: Sequence[Family], fitted_steps: int, n_steps: int
) -> NDArray[np.float64]:
    """Effective counts for windows of ``n_steps`` from those fitted at ``fitted_steps``.

    Scales each family by its ratio of box positions ``Σ_L (T − L + 1)`` over the lengths that
    fit; a family with none that fits in the new window gets ``nan`` (skipped). Exact (a no-op)
    when ``n_steps == fitted_steps``.
    """
    def positions(fam: Family, steps: int) -> int:
        return sum(steps - L + 1 for L in fam if L <= steps)

    out = np.full(len(counts), np.nan)
    for i, (m, fam) in enumerate(zip(counts, fams, strict=True)):
        new, old = positions(fam, n_steps), positions(fam, fitted_steps)
        if new > 0 and old > 0 and np.isfinite(m):
            out[i] = m if new == old else max(m * new / old, 1.0)
    return out


def scan(
    g: FloatArray | Sequence[FloatArray], fams: Sequence[Family],
    norms: Sequence[Sequence[FloatArray | float]], counts: NDArray[np.float64],
) -> FloatArray:
    """Calibrated GLR score (N, T, C): ``−log10`` family-wise p, maximised over the families.

    ``g`` is the residual every family tests, or one per family (a spike and a box may be
    standardised by different noise scales). ``norms[f][i]`` is the template norm of length
    ``fams[f][i]`` (see :func:`family_max`). Families with a ``nan`` count are skipped. Both
    families get the same prior weight (the benchmark draws spikes and local deviations half and
    half), so a weighted-Bonferroni combination adds the same constant to both and is left out.
    """
    per_family = [g] * len(fams) if isinstance(g, np.ndarray) else list(g)
    if len(per_family) != len(fams):
        raise ValueError(f"{len(per_family)} residuals for {len(fams)} families")
    shape = per_family[0].shape
    n = shape[0]
    out = np.empty(shape)
    for start in range(0, n, CHUNK):  # a chunk's arrays stay in the cache: twice as fast
        part = slice(start, start + CHUNK)
        out[part] = _scan_chunk([gf[part] for gf in per_family], fams,
                                [[_rows(v, part, n) for v in fam_norms] for fam_norms in norms],
                                counts)
    return out


#: Windows scanned at a time.
CHUNK = 64


def _rows(value: FloatArray | float, part: slice, n: int) -> FloatArray | float:
    """``value``'s rows of the chunk ``part`` when it has one per window, else ``value``."""
    if isinstance(value, np.ndarray) and value.ndim and value.shape[0] == n and n > 1:
        return value[part]
    return value


def _scan_chunk(
    gs: Sequence[FloatArray], fams: Sequence[Family],
    norms: Sequence[Sequence[FloatArray | float]], counts: NDArray[np.float64],
) -> FloatArray:
    best = np.full(gs[0].shape, -np.inf)
    for g, fam, fam_norms, m in zip(gs, fams, norms, counts, strict=True):
        if not np.isfinite(m):
            continue
        # the calibration is monotone in z, so it commutes with the maxima over boxes
        np.maximum(best, -log10_familywise_p(family_max(g, fam, fam_norms), float(m)), out=best)
    return best


# ----------------------------------------------------------------------------- energy boxes
def energy_z(w: FloatArray, lengths: Family) -> FloatArray:
    """Largest energy statistic covering each sample: (N, T, C).

    For a box of ``L`` samples of the whitened residual ``w`` (N, T, C) the statistic is
    ``Σ w²`` over the box: the GLR of a signal of any shape confined to the box, χ² with ``L``
    degrees of freedom under N(0, 1) noise. It is reported as the |N(0, 1)| value of the same
    tail (the Wilson–Hilferty cube root makes χ²_L normal, then the one-sided tail is read as a
    two-sided one), so that :func:`log10_familywise_p` calibrates it like the boxes. A defect
    whose response rings (a weld's dip excites the wheel on the track at 30–100 Hz) has box
    sums near zero and energy all the same.
    """
    w2 = np.square(w, dtype=np.float64)
    cs = cumulative(w2)
    stats = {}
    for length in lengths:
        if length > w.shape[1]:
            continue
        mean = np.maximum(box_sums(w2, length, cs), 0.0) / length
        b = 2.0 / (9.0 * length)
        z_one = (np.cbrt(mean) - (1.0 - b)) / np.sqrt(b)
        stats[length] = -ndtri_exp(log_ndtr(-z_one) - np.log(2.0))
    return _covering(stats, w.shape)


def energy_score(w: FloatArray, lengths: Family, count: float) -> FloatArray:
    """The energy family's calibrated score (N, T, C): ``−log10`` family-wise p of
    :func:`energy_z` on the whitened residual ``w``, ``count`` its effective number of positions
    (:func:`effective_energy_count`)."""
    return -log10_familywise_p(energy_z(w, lengths), count)


def raise_to_energy(out: FloatArray, w: FloatArray, lengths: Family, count: NDArray[np.float64],
                    fitted_steps: int) -> None:
    """``out`` (N, T, C) raised in place to the energy family's :func:`energy_score` of the
    whitened residual ``w`` (N, T, C), its effective count ``count`` (1,) fitted on windows of
    ``fitted_steps`` and rescaled to ``w``'s (:func:`scale_counts`; nothing where no length
    fits)."""
    m = scale_counts(count, (lengths,), fitted_steps, w.shape[1])[0]
    if np.isfinite(m):
        np.maximum(out, energy_score(w, lengths, float(m)), out=out)


def effective_energy_count(n_steps: int, lengths: Family, n_windows: int, alpha: float,
                           seed: int) -> float:
    """Effective number of independent positions of the energy family (:func:`energy_z`), by
    Monte Carlo on N(0, 1) windows as :func:`effective_counts`; ``nan`` if no length fits."""
    if min(lengths) > n_steps:
        return float("nan")
    rng = np.random.default_rng(seed)
    zmax = np.concatenate([energy_z(rng.standard_normal((min(1000, n_windows - i), n_steps, 1)),
                                    lengths).max(axis=(1, 2))
                           for i in range(0, n_windows, 1000)])
    return count_at(zmax, alpha)
