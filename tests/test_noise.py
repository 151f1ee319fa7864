"""NoisySAN's coloured noise: the documented spectrum, variance and time correlation, reproducible per seed."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ilcsan.rl.methods.coloured_noise import autocorrelation, coloured_noise, window_covariance


def _series(beta: float, shape: tuple[int, ...], seed: int) -> np.ndarray:
    return coloured_noise(beta, shape, torch.Generator().manual_seed(seed)).double().numpy()


def _spectral_slope(series: np.ndarray) -> float:
    power = (np.abs(np.fft.rfft(series, axis=-1)) ** 2).mean(axis=0)
    frequencies = np.fft.rfftfreq(series.shape[-1])
    kept = slice(2, len(frequencies) - 1)
    return float(np.polyfit(np.log(frequencies[kept]), np.log(power[kept]), 1)[0])


@pytest.mark.parametrize("beta", [0.0, 1.0, 2.0])
def test_the_power_spectrum_falls_as_f_to_the_minus_beta(beta):
    series = _series(beta, (500, 1000), 0)
    assert _spectral_slope(series) == pytest.approx(-beta, abs=0.05)


@pytest.mark.parametrize("beta", [0.0, 1.0, 2.0])
def test_variance_about_the_mean_is_one_and_the_constant_term_comes_on_top(beta):
    """E[variance about the series' own mean] = 1 by the normalisation; E[x²] adds the DC term's variance, which
    window_covariance gives (1.00, 1.07, 1.30 for β = 0, 1, 2 and n = 1000)."""
    series = _series(beta, (4000, 1000), 1)
    assert series.var(axis=-1).mean() == pytest.approx(1.0, abs=0.04)
    assert (series ** 2).mean() == pytest.approx(window_covariance(beta, 1000, 1)[0, 0], abs=0.04)
    assert window_covariance(beta, 1000, 1)[0, 0] == pytest.approx((1.0, 1.074, 1.304)[int(beta)], abs=0.002)


def test_white_noise_is_uncorrelated_and_pink_and_brown_are_correlated_in_time():
    white, pink, brown = (_series(beta, (1000, 1000), 2 + index) for index, beta in enumerate((0.0, 1.0, 2.0)))
    assert abs(autocorrelation(white, 1)) < 0.01 and abs(autocorrelation(white, 5)) < 0.01
    assert 0.70 < autocorrelation(pink, 1) < 0.80 and 0.45 < autocorrelation(pink, 5) < 0.55
    assert autocorrelation(brown, 1) > 0.99 and autocorrelation(brown, 5) > 0.95
    assert autocorrelation(pink, 1) > autocorrelation(pink, 5) > autocorrelation(pink, 50) > 0


def test_series_are_independent_across_neurons_and_reproducible_from_the_generator():
    series = _series(1.0, (2, 3, 501), 3)
    assert series.shape == (2, 3, 501)
    assert abs(np.corrcoef(series.reshape(6, -1))[0, 1:]).max() < 0.5
    assert np.array_equal(series, _series(1.0, (2, 3, 501), 3))
    assert not np.array_equal(series, _series(1.0, (2, 3, 501), 4))
    with pytest.raises(ValueError, match="at least 2"):
        coloured_noise(1.0, (4, 1), torch.Generator())


@pytest.mark.parametrize(("beta", "samples"), [(0.0, 1000), (1.0, 1001), (1.0, 5005), (2.0, 1000)])
def test_a_window_of_a_series_has_the_computed_covariance(beta, samples):
    """The windows of T = 5 consecutive samples, pooled over series and offsets, against window_covariance."""
    series = _series(beta, (400, samples), 5)
    offsets = np.arange(0, samples - 5, 7)
    windows = np.stack([series[:, offset:offset + 5] for offset in offsets], axis=1).reshape(-1, 5)
    empirical = windows.T @ windows / len(windows)  # zero-mean process: E[x xᵀ]
    expected = window_covariance(beta, samples, 5)
    assert np.abs(empirical - expected).max() < 0.06 * expected.max()
    if beta == 0.0:
        assert np.allclose(expected, np.eye(5), atol=0.002)
    else:
        assert expected[0, 1] > 0.6 * expected[0, 0]  # neighbours strongly correlated
