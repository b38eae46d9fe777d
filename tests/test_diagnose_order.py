"""Order tracking: a spatial period is a line against travelled distance whatever the speed."""

from __future__ import annotations

import numpy as np
import pytest

from bayesdoor.diagnose import order_log_psd, order_peak
from bayesdoor.systems.door import DOOR_CATALOGUE

FS = 2048.0
SPEEDS = np.array([0.3, 0.4, 0.5])
T_START = np.full(3, 0.25)


def _runs(kappa: float, seed: int, *, amplitude: float = 3.0):
    """Runs of the door's speed profile with a tone of ``kappa`` cycles per metre in white
    noise (its amplitude growing as the speed squared, as an acceleration from a spatial
    period does)."""
    t = np.arange(int(3.6 * FS)) / FS
    v = DOOR_CATALOGUE.speed_profile(SPEEDS, t)
    z = np.cumsum(v, axis=1) / FS
    rng = np.random.default_rng(seed)
    tone = amplitude * (v / SPEEDS[:, None]) ** 2 * np.sin(2 * np.pi * kappa * z)
    x = tone[:, None, :] + rng.standard_normal((3, 2, t.size))
    moving = v > 1e-6
    t_stop = np.array([t[np.flatnonzero(m)[-1]] for m in moving])
    return x, v, t_stop


def test_a_spatial_tone_is_located_in_the_order_spectra():
    kappa = 38.47
    x, v, t_stop = _runs(kappa, 0)
    noise, _, _ = _runs(kappa, 1, amplitude=0.0)
    orders = order_log_psd(x, FS, v, t_start=T_START, t_stop=t_stop, segment_m=0.5)
    reference = order_log_psd(noise, FS, v, t_start=T_START, t_stop=t_stop, segment_m=0.5)
    # the door's stroke is 0.8 m; segments of 0.5 m give bins of 2 / m zero-padded to 0.5 / m
    assert orders.travel_m == pytest.approx(np.full(3, 0.79), abs=0.01)
    assert orders.wavenumbers[1] == pytest.approx(0.5)
    excess = (orders.log_psd - reference.log_psd).mean(axis=1)
    found, sd = order_peak(excess, orders.wavenumbers, 35.0, 0.15)
    # within a tenth of the 2 / m resolution (the tone is 20 dB over the noise)
    assert found == pytest.approx(kappa, abs=0.2)
    assert sd < 0.2


def test_order_peak_is_nan_without_a_peak_in_the_window():
    k = np.arange(0.0, 50.0, 0.5)
    rising = np.tile(k, (3, 1))
    found, sd = order_peak(rising, k, 25.0, 0.1)
    assert np.isnan(found) and np.isnan(sd)


def test_order_spectra_refuse_bad_shapes_and_short_strokes():
    x, v, t_stop = _runs(30.0, 0)
    with pytest.raises(ValueError, match="speed_profiles"):
        order_log_psd(x, FS, v[:2], t_start=T_START, t_stop=t_stop, segment_m=0.5)
    with pytest.raises(ValueError, match=r"segment_m=2\.0"):
        order_log_psd(x, FS, v, t_start=T_START, t_stop=t_stop, segment_m=2.0)
