"""The rails' height from two axle boxes: the wheelset's response identified from recordings
alone (against the physics world's own transfer functions), the height it gives, the weld test
on it, and one-line errors."""

from __future__ import annotations

import numpy as np
import pytest

from railwatch.detection import welds
from railwatch.errors import RailwatchError
from railwatch.physics.dynamics import coupled, on_bins
from railwatch.physics.features import Item
from railwatch.physics.passes import PassPlan, simulate_pass
from railwatch.physics.world import DX_M, World, build_track
from railwatch.recordings import rails

pytestmark = pytest.mark.slow  # a 3-km physics track and three passes: about 30 s

WELDS = (Item(0, "weld", 1000.0, 0.9, 0.4, 1, (("crown_mm", 0.0), ("crown_m", 0.1))),
         Item(1, "weld", 2000.0, 0.8, 0.35, 2, (("crown_mm", 0.1), ("crown_m", 0.1))))


@pytest.fixture(scope="module")
def world():  # type: ignore[no-untyped-def]
    """Two training passes (both ways, 10-30 m/s) over a 3-km track with two welds, and a
    third pass with its clean twin."""
    w = World(length_m=3000.0)
    track = build_track(w, 11, items=(list(WELDS), []))
    runs = [simulate_pass(track, PassPlan(direction=d), seed=s)
            for d, s in ((1, 1), (-1, 2), (1, 3))]
    response = rails.identify([(p.columns["axle_left"], p.columns["axle_right"],
                                p.columns["speed"]) for p in runs[:2]], 2000.0)
    return w, track, runs, response


def _model_gain(w: World, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The physics world's bounce and roll displacement gain of the leading wheelset."""
    h = on_bins(coupled(w.vehicle, w.track, 4000.0).freqs,
                coupled(w.vehicle, w.track, 4000.0).sensor_transfer, f)
    g = h[:, :2, :2] / (-(2 * np.pi * f) ** 2)[:, None, None]
    return np.abs(g[:, 0, 0] + g[:, 0, 1]), np.abs(g[:, 0, 0] - g[:, 0, 1])


def test_the_identified_response_is_the_worlds_own(world) -> None:  # type: ignore[no-untyped-def]
    """Identified from the recordings alone, without the rails' height: bounce and roll within
    20 % of the model's gain from 3 to 600 Hz (two passes of 3 km; the smoothing fills in the
    notch just above P2), P2 within 1 Hz of the model's peak."""
    w, _, _, response = world
    f = np.geomspace(3.0, 600.0, 200)
    grid = np.log(np.asarray(response.freq_hz))
    for identified, model in zip((response.bounce, response.roll), _model_gain(w, f),
                                 strict=True):
        found = np.exp(np.interp(np.log(f), grid, identified))
        ratio = found / (model / model[0])  # the gauge: 1 where the wheel follows the rail
        assert np.all(np.abs(ratio - 1) < 0.2), (ratio.min(), ratio.max())
    fine = np.linspace(20, 200, 3601)
    assert response.p2_hz == pytest.approx(fine[np.argmax(_model_gain(w, fine)[0])], abs=1.0)


def test_the_height_follows_the_rail(world) -> None:  # type: ignore[no-untyped-def]
    """The clean twin's axle boxes give the rails' height under the wheels: 95 % correlated
    with the true wheel path over wavelengths of 0.1-3 m."""
    _, track, runs, response = world
    twin = runs[2].twin
    heights = rails.rail_heights(twin["axle_left"], twin["axle_right"], response)
    x = np.asarray(twin["position"])
    true = np.stack([np.interp(x, track.x0 + DX_M * np.arange(track.clean.shape[1]), rail)
                     for rail in track.clean])

    def band(z: np.ndarray) -> np.ndarray:
        f = np.fft.rfftfreq(z.shape[1], 1 / 2000.0)
        v = float(np.median(twin["speed"]))
        keep = (f >= v / 3.0) & (f <= v / 0.1)
        return np.fft.irfft(np.fft.rfft(z, axis=1) * keep, z.shape[1], axis=1)[:, 40_000:-40_000]

    for measured, rail in zip(band(heights), band(true), strict=True):
        assert np.corrcoef(measured, rail)[0, 1] > 0.95


def test_the_weld_test_finds_both_welds_and_not_on_the_twin(world) -> None:  # type: ignore[no-untyped-def]
    """The geometry bound (the same test on the true height, the spectra of clean tracks) gives
    these welds z = 5.5 (crownless) and 9.9; one pass gives 5.1 and 9.6, its twin (the same pass
    without the welds) 3.6 and 4.2 at the same places."""
    _, _, runs, response = world
    out = {}
    for name, cols in (("pass", runs[2].columns), ("twin", runs[2].twin)):
        position, z = welds.weld_evidence(cols["axle_left"], cols["axle_right"], cols["speed"],
                                          np.asarray(cols["position"]), response)
        out[name] = (position, np.fmax(z[:, 0], z[:, 1]))
    for it in WELDS:
        at = [float(np.nanmax(np.where(np.abs(p - it.position_m - it.length_m / 2) <= 3, z,
                                       np.nan))) for p, z in out.values()]
        assert at[0] > max(4.5, at[1] + 1.0), (it, at)
    position, z = out["twin"]
    assert np.nanmedian(z) < 3.0  # the texture: the bank's highest of about 24 N(0, 1) tests
    assert np.isnan(z[np.abs(position - position[0]) < welds.EDGE_M - 1]).all()


def test_minimum_phase_recovers_a_minimum_phase_filter() -> None:
    n = 4096
    w = np.exp(-2j * np.pi * np.fft.rfftfreq(n))  # e^{-iω}
    h = 1.0 / (1.0 - 0.9 * w) * (1.0 - 0.5 * w)  # pole and zero inside the unit circle
    assert rails.minimum_phase(np.abs(h)) == pytest.approx(h, rel=1e-6)


def test_the_response_is_saved_and_read_back(world) -> None:  # type: ignore[no-untyped-def]
    response = world[3]
    assert rails.AxleResponse.from_dict(response.to_dict()).p2_hz == pytest.approx(
        response.p2_hz, abs=0.01)
    with pytest.raises(ValueError, match="damaged"):
        rails.AxleResponse.from_dict({"fs": 2000.0, "freq_hz": [1, 2], "bounce": [0.0]})


def test_one_speed_or_too_little_recording_is_a_one_line_error(world) -> None:  # type: ignore[no-untyped-def]
    cols = world[2][0].columns
    steady = np.full(len(cols["speed"]), 20.0)
    with pytest.raises(RailwatchError, match="times apart") as e:
        rails.identify([(cols["axle_left"], cols["axle_right"], steady)], 2000.0)
    assert "\n" not in str(e.value)
    with pytest.raises(RailwatchError, match="give more recordings"):
        rails.identify([(cols["axle_left"][:20_000], cols["axle_right"][:20_000],
                         cols["speed"][:20_000])], 2000.0)
