"""Coloured Gaussian noise, the time-correlated noise of NoisySAN (Chen, Peng, Huang, Tian, arXiv 2403.04162).

NoisySAN perturbs a spiking actor during exploration with noise whose power spectrum falls as S(f) ∝ f^−β:
β = 0 is white noise, β = 1 pink (the paper finds pink best), β = 2 brown (a random walk). One series per
neuron runs along time, across the T simulation steps of an action and across the steps of an episode, so
successive steps see correlated perturbations.

The series is drawn in the frequency domain (Timmer & König 1995, A&A 300, 707, the method of SpikingJelly's
NoisySAN example): for the n-sample rfft frequencies f_j = j/n, j = 0..⌊n/2⌋, independent Gaussian real and
imaginary parts with standard deviation s_j = max(f_j, 1/n)^(−β/2) (frequencies below the lowest non-zero one
are flat), a real DC term (and Nyquist term when n is even), then the inverse rfft divided by the theoretical
standard deviation of the non-constant part, σ = (2/n)·sqrt(Σ_{j≥1} w_j²), w_j = s_j except w_{n/2} = s_{n/2}/2
for even n. So a series' variance about its own mean is ≈ 1 (measured 1.00, 1.01, 1.03 for β = 0, 1, 2 and
n = 1000); its random constant (the DC term) comes on top: E[x²] ≈ 1.00, 1.08, 1.33.

Not yet wired into the actor: NoisySAN's exploration itself is still to be built on this.
"""

from __future__ import annotations

import numpy as np


def coloured_noise(beta: float, shape: tuple[int, ...], generator: np.random.Generator) -> np.ndarray:
    """Unit-variance Gaussian noise with power spectrum ∝ f^−β along the last axis of ``shape`` (time); all other
    axes are independent series. float64, from ``generator`` only (reproducible, checkpointable)."""
    samples = shape[-1]
    if samples < 2:
        raise ValueError(f"coloured noise needs at least 2 samples in time, got {samples}")
    frequencies = np.fft.rfftfreq(samples)
    scale = np.maximum(frequencies, 1.0 / samples) ** (-beta / 2.0)
    weights = scale[1:].copy()
    if samples % 2 == 0:
        weights[-1] /= 2.0  # the Nyquist term is real: half the power of a complex pair
    sigma = 2.0 * np.sqrt(np.sum(weights ** 2)) / samples
    spectrum_shape = (*shape[:-1], len(frequencies))
    real = generator.normal(size=spectrum_shape) * scale
    imaginary = generator.normal(size=spectrum_shape) * scale
    imaginary[..., 0] = 0.0
    real[..., 0] *= np.sqrt(2.0)
    if samples % 2 == 0:
        imaginary[..., -1] = 0.0
        real[..., -1] *= np.sqrt(2.0)
    return np.fft.irfft(real + 1j * imaginary, n=samples, axis=-1) / sigma


def autocorrelation(series: np.ndarray, lag: int) -> float:
    """The sample autocorrelation at ``lag`` of series along the last axis, averaged over all other axes."""
    centred = series - series.mean(axis=-1, keepdims=True)
    numerator = (centred[..., lag:] * centred[..., :-lag]).mean(axis=-1)
    return float(np.mean(numerator / centred.var(axis=-1)))
