"""The strength figure of ``scripts/diagnosis_strength.py`` on signals with known spectra.

``effect_z`` divides the change of a run's log10 Welch PSD by the run's Welch standard
deviation; these tests check that scale against the chi-square theory of the Welch estimate
and against the analytic PSD of a tone in white noise, independently of the rig.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
from diagnosis_strength import effect_z, summarise

FS = 2048.0
RUNS, CHANNELS = 8, 4
BAND = (4.0, 96.0)


def _window(seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """Every run's motion window: from 0.5 s to 0.5 s before the end."""
    return np.full(RUNS, 0.5), np.full(RUNS, seconds - 0.5)


def _noise(seed: int, seconds: float, sd: float = 0.01) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return sd * rng.standard_normal((RUNS, CHANNELS, int(seconds * FS)))


def test_independent_noise_gives_z_of_variance_two():
    """Two independent records of the same noise differ by two Welch scatters: var(z) = 2.

    8 runs x 4 channels x 93 bins = 2976 values, about half of them independent (Hann bins
    1 Hz apart are correlated); the sample variance of ``z`` then has a standard error of
    about 2 sqrt(2 / 1500) = 0.07, and the tolerance 0.3 is four of them. The mean's
    standard error is sqrt(2 / 1500) = 0.04 (the log bias cancels in the difference).
    """
    freqs, z, sd = effect_z(_noise(1, 4.0), _noise(2, 4.0), FS, *_window(4.0), BAND)
    assert freqs[0] == BAND[0] and freqs[-1] == BAND[1] and z.shape == (RUNS, CHANNELS, 93)
    assert np.all(sd > 0)
    assert abs(np.var(z) - 2.0) < 0.3, np.var(z)
    assert abs(np.mean(z)) < 0.15, np.mean(z)


def test_a_tone_on_the_same_noise_gives_its_analytic_log_change():
    """A 40 Hz tone of amplitude A added to white noise of standard deviation s.

    Hann-windowed Welch PSD: the tone's bin holds (A^2 / 2) / ENBW with ENBW = 1.5 Hz, the
    noise 2 s^2 / fs, so the change is log10(1 + ratio) less the noise estimate's log scatter
    about its expectation. With 39 s windows (77 segments, sd 0.05 decades per bin) that
    scatter averages over 8 runs x 4 channels to a standard error of 0.009 decades (its bias
    -0.003); the tone's cross term with the same noise averages to about
    2 sqrt(ratio / 77 / 32) of the noise level, 0.003 decades: tolerance 0.04 decades, four
    standard errors. On-bin, a Hann window puts the tone into its bin and the two neighbours
    only, so two bins away and more the change is zero (to rounding).
    """
    noise, amplitude, s = _noise(3, 40.0), 0.004, 0.01
    t = np.arange(noise.shape[-1]) / FS
    tone = amplitude * np.sin(2.0 * np.pi * 40.0 * t + 0.3)
    freqs, z, sd = effect_z(noise + tone, noise, FS, *_window(40.0), BAND)
    ratio = (amplitude**2 / 2.0 / 1.5) / (2.0 * s**2 / FS)
    change = (z * sd[:, None, None]).mean(axis=(0, 1))
    at = int(np.argmin(np.abs(freqs - 40.0)))
    assert abs(change[at] - np.log10(1.0 + ratio)) < 0.04, (change[at], np.log10(1 + ratio))
    far = np.abs(freqs - 40.0) > 1.5
    assert np.max(np.abs(change[far])) < 1e-6
    summary = summarise(freqs, z, ["a", "b", "c", "d"])
    assert summary["z_max_at"]["hz"] == 40.0 and summary["z_mean_max_at"]["hz"] == 40.0
    assert summary["lambda"] == np.sum(z**2)
