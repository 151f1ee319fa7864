"""NoisySAN's coloured noise: the documented spectrum, variance and time correlation, reproducible per seed."""

from __future__ import annotations

import numpy as np
import pytest

from ilcsan.snn.noise import autocorrelation, coloured_noise


def _spectral_slope(series: np.ndarray) -> float:
    power = (np.abs(np.fft.rfft(series, axis=-1)) ** 2).mean(axis=0)
    frequencies = np.fft.rfftfreq(series.shape[-1])
    kept = slice(2, len(frequencies) - 1)
    return float(np.polyfit(np.log(frequencies[kept]), np.log(power[kept]), 1)[0])


@pytest.mark.parametrize("beta", [0.0, 1.0, 2.0])
def test_the_power_spectrum_falls_as_f_to_the_minus_beta(beta):
    series = coloured_noise(beta, (500, 1000), np.random.default_rng(0))
    assert _spectral_slope(series) == pytest.approx(-beta, abs=0.05)


@pytest.mark.parametrize(("beta", "variance", "mean_square"), [(0.0, 1.00, 1.00), (1.0, 1.01, 1.08),
                                                               (2.0, 1.03, 1.33)])
def test_variance_about_the_mean_is_one_and_the_constant_term_comes_on_top(beta, variance, mean_square):
    series = coloured_noise(beta, (4000, 1000), np.random.default_rng(1))
    assert series.var(axis=-1).mean() == pytest.approx(variance, abs=0.02)
    assert (series ** 2).mean() == pytest.approx(mean_square, abs=0.03)


def test_white_noise_is_uncorrelated_and_pink_and_brown_are_correlated_in_time():
    rng = np.random.default_rng(2)
    white, pink, brown = (coloured_noise(beta, (1000, 1000), rng) for beta in (0.0, 1.0, 2.0))
    assert abs(autocorrelation(white, 1)) < 0.01 and abs(autocorrelation(white, 5)) < 0.01
    assert 0.70 < autocorrelation(pink, 1) < 0.80 and 0.45 < autocorrelation(pink, 5) < 0.55
    assert autocorrelation(brown, 1) > 0.99 and autocorrelation(brown, 5) > 0.95
    assert autocorrelation(pink, 1) > autocorrelation(pink, 5) > autocorrelation(pink, 50) > 0


def test_series_are_independent_across_neurons_and_reproducible_from_the_generator():
    series = coloured_noise(1.0, (2, 3, 501), np.random.default_rng(3))
    assert series.shape == (2, 3, 501)
    assert abs(np.corrcoef(series.reshape(6, -1))[0, 1:]).max() < 0.5
    assert np.array_equal(series, coloured_noise(1.0, (2, 3, 501), np.random.default_rng(3)))
    with pytest.raises(ValueError, match="at least 2"):
        coloured_noise(1.0, (4, 1), np.random.default_rng(0))
