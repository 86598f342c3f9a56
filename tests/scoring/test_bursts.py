"""The burst model: the best short oscillation against a brute-force search, taken out where it
is a burst, left where it is a box or a spike."""

from __future__ import annotations

import numpy as np
import pytest

from railwatch.scoring.bursts import best_burst, energy_peak, frequency_grid

LENGTHS = tuple(range(5, 21))
MARGIN, MINIMUM, RATIO = 12.0, 20.0, 0.5


def burst(n: int, start: int, length: int, freq: float, amplitude: float = 3.0) -> np.ndarray:
    t = np.arange(n)
    on = (t >= start) & (t < start + length)
    return amplitude * np.sin(2 * np.pi * freq * t + 1.0) * on


def brute_force(w: np.ndarray, peak: int) -> tuple[float, np.ndarray]:
    """The largest energy of a least-squares [cos, sin] atom over every span covering ``peak``
    and every frequency of the grid, one lstsq at a time, and that atom laid in the window."""
    n = len(w)
    t = np.arange(n)
    best, fit = -1.0, np.zeros(n)
    for length in LENGTHS:
        for start in range(max(0, peak - length + 1), min(peak, n - length) + 1):
            span = t[start:start + length]
            for f in frequency_grid(length, max(LENGTHS), 4.0):
                design = np.stack([np.cos(2 * np.pi * f * span), np.sin(2 * np.pi * f * span)], 1)
                coef, _, rank, _ = np.linalg.lstsq(design, w[start:start + length], rcond=None)
                energy = float(((design @ coef) ** 2).sum())
                if rank == 2 and energy > best:
                    best, fit = energy, np.zeros(n)
                    fit[start:start + length] = design @ coef
    return best, fit


@pytest.mark.parametrize("where", [90, 0, 185])  # inside, and against either end of the window
def test_best_atom_is_the_brute_force_one(where: int) -> None:
    rng = np.random.default_rng(where)
    w = rng.standard_normal((3, 200))
    w += burst(200, where, 15, 0.23)
    found = best_burst(w, LENGTHS, 4.0, MARGIN, MINIMUM, RATIO)
    peaks = energy_peak(w, min(LENGTHS))
    for i in range(3):
        energy, fit = brute_force(w[i], int(peaks[i]))
        assert found.energy[i] == pytest.approx(energy, rel=1e-9)
        np.testing.assert_allclose(found.fit[i], fit if found.kept[i] else 0.0, atol=1e-9)


# bursts of about 64 noise variances (8 std over the span), fast and short to slow and long;
# near the Nyquist frequency 8 samples carry less of the amplitude (about 54), and a spike
# explains more of them: 86 % are taken out there
@pytest.mark.parametrize("freq,length,amplitude,share", [(0.45, 8, 4.0, 0.8), (0.23, 15, 3.0, 0.9),
                                                         (0.12, 20, 2.5, 0.9)])
def test_a_burst_is_taken_out(freq: float, length: int, amplitude: float, share: float) -> None:
    rng = np.random.default_rng(7)
    noise = rng.standard_normal((50, 200))
    w = noise + burst(200, 80, length, freq, amplitude)
    found = best_burst(w, LENGTHS, 4.0, MARGIN, MINIMUM, RATIO)
    assert found.kept.mean() >= share
    left = w - found.fit
    # where it is taken out, what is left of its span is about the noise
    span, kept = slice(80, 80 + length), found.kept
    left_energy = ((left[kept, span] - noise[kept, span]) ** 2).sum(1).mean()
    assert left_energy < 0.15 * (w[kept, span] ** 2).sum(1).mean()


@pytest.mark.parametrize("kind", ["box", "spike", "noise"])
def test_a_defect_or_noise_is_left_alone(kind: str) -> None:
    rng = np.random.default_rng(3)
    w = rng.standard_normal((200, 200))
    if kind == "box":
        w[:, 100:112] += 2.0  # 2 noise std over 12 samples: a box at 6.9 std of its test
    elif kind == "spike":
        w[:, 100] += 6.0
    found = best_burst(w, LENGTHS, 4.0, MARGIN, MINIMUM, RATIO)
    # noise alone lends a 2-parameter atom a large energy somewhere now and then
    assert found.kept.mean() <= (0.1 if kind == "noise" else 0.02)
    np.testing.assert_array_equal(found.fit[~found.kept], 0.0)


def test_a_window_shorter_than_the_longest_atom() -> None:
    rng = np.random.default_rng(5)
    w = rng.standard_normal((20, 16))
    w[:, 4:12] += burst(16, 4, 8, 0.3, 4.0)[4:12]
    found = best_burst(w, LENGTHS, 4.0, MARGIN, MINIMUM, RATIO)
    assert found.fit.shape == w.shape and np.all(found.start + found.length <= 16)
    assert found.kept.mean() >= 0.8


def test_two_bursts_one_look_each() -> None:
    """What the detector's ``burst_count`` 2 does: a second look after the first burst is taken
    out finds the other; atoms longer than the boxes they are weighed against
    (``burst_max_length``) follow a 25-sample burst."""
    rng = np.random.default_rng(8)
    noise = rng.standard_normal((30, 200))
    w = noise + burst(200, 40, 15, 0.3, 4.0) + burst(200, 140, 25, 0.2, 2.5)
    long_atoms = tuple(range(5, 31))
    first = best_burst(w, long_atoms, 4.0, MARGIN, MINIMUM, RATIO, LENGTHS)
    second = best_burst(w - first.fit, long_atoms, 4.0, MARGIN, MINIMUM, RATIO, LENGTHS)
    assert first.kept.all() and second.kept.all()
    starts = np.sort(np.stack([first.start, second.start]), axis=0)
    assert np.all(np.abs(starts[0] - 40) < 10) and np.all(np.abs(starts[1] - 140) < 15)
    lengths = np.where(first.start > 100, first.length, second.length)  # the long burst's atom
    assert np.median(lengths) >= 20


def test_each_series_on_its_own() -> None:
    """A series' burst does not depend on the other series searched with it: the detector's
    second look searches only the series where the first took one out, and must find there what
    a search of every series finds."""
    rng = np.random.default_rng(9)
    w = rng.standard_normal((64, 200))
    w[::3] += burst(200, 70, 12, 0.3, 4.0)
    whole = best_burst(w, LENGTHS, 4.0, MARGIN, MINIMUM, RATIO)
    some = np.flatnonzero(whole.kept | (np.arange(64) % 5 == 0))
    part = best_burst(w[some], LENGTHS, 4.0, MARGIN, MINIMUM, RATIO)
    assert 0 < whole.kept.sum() < 64
    for name in ("kept", "start", "length", "freq"):
        np.testing.assert_array_equal(getattr(part, name), getattr(whole, name)[some])
    np.testing.assert_allclose(part.fit, whole.fit[some], atol=1e-12)
    np.testing.assert_allclose(part.energy, whole.energy[some], rtol=1e-12)
