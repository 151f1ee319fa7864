"""Coloured Gaussian noise, the series NoisySAN (Chen, Peng, Huang, Tian, arXiv 2403.04162) explores with.

The noise's power spectrum falls as S(f) ∝ f^−β: β = 0 is white noise, β = 1 pink (the paper finds pink best),
β = 2 brown (a random walk). One series per noise channel runs along time, across the T simulation steps of an
action and across the steps of an episode, so successive steps see correlated perturbations
(:mod:`ilcsan.rl.methods.noisysan` draws them and says where they enter, :class:`~ilcsan.snn.noise.NeuronNoise`).

The series is drawn in the frequency domain (Timmer & König 1995, A&A 300, 707, the method of SpikingJelly's
NoisySAN example): for the n-sample rfft frequencies f_j = j/n, j = 0..⌊n/2⌋, independent Gaussian real and
imaginary parts with standard deviation s_j = max(f_j, 1/n)^(−β/2) (frequencies below the lowest non-zero one
are flat), a real DC term (and Nyquist term when n is even), then the inverse rfft divided by the theoretical
standard deviation of the non-constant part, σ = (2/n)·sqrt(Σ_{j≥1} w_j²), w_j = s_j except w_{n/2} = s_{n/2}/2
for even n. So a series' variance about its own mean is 1 in expectation; its random constant (the DC term)
comes on top: E[x²] = 1.00, 1.07, 1.30 for β = 0, 1, 2 and n = 1000.

Because the Fourier coefficients are independent, such a series is a circular stationary Gaussian process:
any window of w consecutive samples is N(0, Σ) with the Toeplitz covariance of :func:`window_covariance`.
"""

from __future__ import annotations

import math

import numpy as np
import torch


def _spectrum_scales(beta: float, samples: int) -> tuple[np.ndarray, float]:
    """(s_j for the rfft frequencies, σ of the non-constant part) of the module docstring, float64."""
    frequencies = np.fft.rfftfreq(samples)
    scale = np.maximum(frequencies, 1.0 / samples) ** (-beta / 2.0)
    weights = scale[1:].copy()
    if samples % 2 == 0:
        weights[-1] /= 2.0  # the Nyquist term is real: half the power of a complex pair
    return scale, 2.0 * math.sqrt(float(np.sum(weights ** 2))) / samples


def fft_length(samples: int) -> int:
    """The smallest length ≥ ``samples`` whose prime factors are all 2, 3, 5 or 7: the lengths an FFT library's
    mixed-radix transforms handle fastest (a length with a large prime factor, such as 5 005 = 5·7·11·13, takes a
    slower path)."""
    length = max(1, samples)
    while True:
        rest = length
        for prime in (2, 3, 5, 7):
            while rest % prime == 0:
                rest //= prime
        if rest == 1:
            return length
        length += 1


def coloured_noise(beta: float, shape: tuple[int, ...], generator: torch.Generator) -> torch.Tensor:
    """Unit-variance Gaussian noise with power spectrum ∝ f^−β along the last axis of ``shape`` (time); all other
    axes are independent series. float32, from ``generator`` only (reproducible, checkpointable)."""
    samples = shape[-1]
    if samples < 2:
        raise ValueError(f"coloured noise needs at least 2 samples in time, got {samples}")
    scale_np, sigma = _spectrum_scales(beta, samples)
    scale = torch.as_tensor(scale_np, dtype=torch.float32)
    parts = torch.randn((*shape[:-1], len(scale_np), 2), generator=generator)  # real and imaginary parts
    parts *= scale[:, None]
    parts[..., 0, 1] = 0.0  # the DC term is real
    parts[..., 0, 0] *= math.sqrt(2.0)
    if samples % 2 == 0:
        parts[..., -1, 1] = 0.0
        parts[..., -1, 0] *= math.sqrt(2.0)
    series = torch.fft.irfft(torch.view_as_complex(parts), n=samples, dim=-1)
    return series.mul_(1.0 / sigma)


def window_covariance(beta: float, samples: int, window: int) -> np.ndarray:
    """Covariance (window, window) of ``window`` consecutive samples of :func:`coloured_noise` series of length
    ``samples``: c(τ) = (2 s_0² + 4 Σ_{0<j<n/2} s_j² cos(2πjτ/n) + 2 s_{n/2}² (−1)^τ [n even]) / (nσ)²."""
    scale, sigma = _spectrum_scales(beta, samples)
    power = 4.0 * scale ** 2
    power[0] = 2.0 * scale[0] ** 2
    if samples % 2 == 0:
        power[-1] = 2.0 * scale[-1] ** 2
    lags = np.arange(window)
    frequencies = np.arange(len(scale))
    covariance = np.cos(2 * np.pi * np.outer(lags, frequencies) / samples) @ power / (samples * sigma) ** 2
    return covariance[np.abs(lags[:, None] - lags[None, :])]


def autocorrelation(series: np.ndarray, lag: int) -> float:
    """The sample autocorrelation at ``lag`` of series along the last axis, averaged over all other axes."""
    centred = series - series.mean(axis=-1, keepdims=True)
    numerator = (centred[..., lag:] * centred[..., :-lag]).mean(axis=-1)
    return float(np.mean(numerator / centred.var(axis=-1)))
