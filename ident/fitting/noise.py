"""Load-sensor noise estimates.

The identifier uses **one** noise estimate for everything it reports and decides (``residual_noise_std``): the white
part of the load residual at the whole-log optimum. The model-free estimates below only seed the first fitting
window's weights (the load rows against the encoder rows), before any model has been fitted.

Why the residual, and why its first differences: after the fit, the residual is the sensor noise plus whatever the
model misses. The misfit of a model that lacks an effect is smooth on the scale of a sample (it follows the motion:
ringing at a few % of the sample rate, slides, breakaways), while the sensor's noise is white; first differences keep
the white part (variance 2 sigma^2) and suppress a misfit at frequency f by (2 sin(pi f / rate))^2 (0.1 at 5 % of the
rate). Estimating the noise from the raw signal instead (quiet stretches, or high-order differences) fails on logs
whose load never stops ringing, on slow sample rates (1 kHz: the ringing survives any difference) and on steps
(issue 21 measured 5.2x and 28.7x); the residual does not contain the motion.

A misfit can also ring (a fit trapped on the wrong frequency leaves the residual oscillating at the ringing,
hundreds of times the noise), and then the differences do not suppress it enough; the upper half-band of the
residual's spectrum (above a quarter of the sample rate) holds none of it, so that band's estimate replaces the
differences' when it is clearly lower (``residual_noise_std``).

Limit, said plainly: a misfit above a quarter of the sample rate survives both and is counted as noise, so a missing
effect that only shows at such frequencies cannot be told from noise.
"""
from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

MAD_TO_SIGMA = 1.0 / 0.6744897501960817  # a Gaussian's standard deviation over its median absolute deviation


def residual_noise_std(residual: np.ndarray) -> float:
    """White-noise level [same unit as ``residual``] of a fit's residual, from two estimates that are both right on
    white noise and each blind to one kind of misfit:

    - the median absolute first difference, scaled for a Gaussian (MAD / 0.6745 / sqrt(2)): the median makes the
      few samples where a model that misses an effect mistimes a breakaway (a jump in the residual) irrelevant;
    - the median power of the residual's upper half-band (``high_band_noise_std``): a misfit that rings (a fit
      trapped on the wrong frequency leaves a residual oscillating at the ringing, hundreds of times the noise, which
      the first differences only suppress to (2 sin(pi f / rate))^2: measured 13.8x and 170x the sensor noise on
      two chirps) has no power there.

    The first is the estimate unless the second is below it by more than ``AGREE_SIGMAS`` standard deviations of
    their relative difference on white noise (``DIFFERENCE_SCATTER`` / sqrt(n)): a plain minimum would bias every
    good fit's estimate low by 1-4 %."""
    d = np.diff(np.asarray(residual, dtype=float))
    if d.size == 0:
        return 0.0
    mad = float(np.median(np.abs(d - np.median(d))) * MAD_TO_SIGMA / math.sqrt(2.0))
    high = high_band_noise_std(residual)
    return high if mad > high * (1.0 + AGREE_SIGMAS * DIFFERENCE_SCATTER / math.sqrt(d.size)) else mad


AGREE_SIGMAS = 5.0
#: sqrt(n) x the standard deviation of the two estimates' relative difference on white noise (measured: 1.4 and 1.8
#: for each, 2.3 for their difference)
DIFFERENCE_SCATTER = 2.3
HIGH_BAND = 0.25   # the band [HIGH_BAND x rate, rate / 2) read by ``high_band_noise_std``


#: sqrt(n) x the standard deviation of ``residual_noise_std``'s estimate over the true sigma, n white samples
#: (measured: 1.27 and 1.25 over 400 draws of 3,500 and of 35,000 samples)
ESTIMATE_SCATTER = 1.3


def at_noise_level(n_part: int, n_noise: int, alpha: float) -> float:
    """The ratio ``rms(residual part) / sigma_hat`` that a model reproducing its log (a residual of white noise)
    exceeds with probability about ``alpha``: 1 + z_alpha sqrt(1 / (2 n_part) + ESTIMATE_SCATTER^2 / n_noise).

    ``n_part``: the residuals whose RMS is compared; ``n_noise``: the residuals ``sigma_hat`` was estimated from
    (``residual_noise_std``). The RMS of n white samples scatters by 1 / sqrt(2 n) of sigma, the estimate by
    ``ESTIMATE_SCATTER`` / sqrt(n_noise). Adding the two variances treats them as independent. On a part that is
    also the estimate's own data they are correlated and the ratio scatters less (measured: sqrt(n) x its standard
    deviation 1.11, against 1.57 assumed here), so the level is a little high there; on another part (held back) it
    is right (measured 0.0094 against 0.0095 at 15,000 and 35,000 samples)."""
    z = NormalDist().inv_cdf(1.0 - alpha)
    return 1.0 + z * math.sqrt(0.5 / n_part + ESTIMATE_SCATTER ** 2 / n_noise)


def high_band_noise_std(x: np.ndarray) -> float:
    """White-noise level of ``x`` from its periodogram above ``HIGH_BAND`` x the sample rate (Hann window): white
    noise of variance sigma^2 has a flat periodogram whose bins are sigma^2 chi^2_2 / 2, median sigma^2 ln 2; the
    median ignores narrow lines. inf for fewer than 128 samples (too few bins to tell)."""
    x = np.asarray(x, dtype=float)
    if x.size < 128:
        return math.inf
    win = np.hanning(x.size)
    power = np.abs(np.fft.rfft((x - x.mean()) * win)) ** 2 / float(np.sum(win ** 2))
    band = power[int(math.ceil(HIGH_BAND * x.size)):-1]
    return float(math.sqrt(np.median(band) / math.log(2.0)))


def white_noise_std(y: np.ndarray) -> float:
    """Model-free white-noise level of a sampled signal: the median absolute 4th difference / (0.6745 sqrt(70)).

    A 4th difference of white noise has the variance 70 sigma^2, while a motion slow against the sample rate nearly
    vanishes in it ((w dt)^4: 1e-4 of the amplitude for an 80 Hz ringing at 5 kHz); the median ignores the pulses'
    jumps. It assumes the signal is slow for at least half of the samples (not so at 1 kHz with a fast ringing); the
    identifier uses it only as the first window's starting weight. The discrepancy workflow's noise floor uses it."""
    d4 = np.diff(np.asarray(y, dtype=float), 4)
    if d4.size == 0:
        return 0.0
    return float(np.median(np.abs(d4 - np.median(d4))) * MAD_TO_SIGMA / math.sqrt(70.0))


def noise_std(y: np.ndarray) -> float:
    """White-noise level of a signal from its quiet stretches: std of second differences / sqrt(6) in windows of
    25 samples; the windows within 1.5x of the 10th percentile hold nothing but noise (a stuck body), and their
    median is the estimate. Kept for callers outside the identifier; it reads high when the load rings most of the
    time (measured 5x on step logs, issue 21), which is why the identifier no longer uses it."""
    d2 = np.diff(y, 2)
    w = 25
    if d2.size < 4 * w:
        return float(np.std(d2) / math.sqrt(6))
    stds = d2[: d2.size // w * w].reshape(-1, w).std(axis=1, ddof=1)
    quiet = stds[stds <= 1.5 * np.percentile(stds, 10)]
    return float(np.median(quiet) / math.sqrt(6))
