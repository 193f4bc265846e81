"""The identifier's data-driven start (no user guess): the load's free ringing while the motor is stuck.

While the motor stands still, the load is a one-body oscillator on a fixed spring: J_l q_l'' = -K_s q_l
- f_l sgn(q_l') + const. Its frequency w_l = sqrt(K_s/J_l) and its Coulomb decay f_l/J_l are read off the log; the
scale J_l* is left to the first window's grid (``identify._first_stage``).

**Free-ringing segments** (``free_ringing_segments``): runs of a constant encoder count, cut wherever the commanded
torque exceeds the motor's Coulomb level f_m (a pulse or a step that can move the motor inside one count: a one-way
pulse train moves the motor by less than a count per pulse, so a constant count alone would span many pulses and the
spectrum would show the pulse staircase -- issue 21's "2 Hz ringing"). Only runs of at least
``MIN_SEGMENT_SAMPLES`` samples are used.

**Frequency**: the peak of the summed (Hann-windowed, detrended, zero-padded) power spectra of the segments: each
segment's own spectrum, so that the joins between segments add no broadband steps. **Decay**: a linear least-squares
fit of the load's acceleration on position and velocity sign (Savitzky-Golay derivatives, a window of 1/8 ringing
period), an offset per segment removed by demeaning within each segment (no per-segment dummy columns: their size
grew with rows x segments, the superlinear memory of issue 21).

The spectral peak of free ringing is the start's frequency (``frequency_trusted``) when it stands clear of the noise
(``MIN_CONTRAST``) and either the least-squares frequency agrees with it within ``CONSISTENT_W2`` (``consistent``;
their disagreement is then the uncertainty the first grid spans, ``w_l2_spread``: a PD log had 1.23 in w_l^2, the
peak 19 % below the truth) or it is a peak (a local maximum, not the band's lowest bin on a rising drift) that
comes from several segments over at least two of its periods (``MIN_SEGMENTS``,
``MIN_CONTRAST``, ``MIN_PERIODS``; a pulse train every 56 ms on a 17.7 Hz ringing showed a resolution-bound peak at
12.5 Hz; the Savitzky-Golay derivatives lose accuracy below ~16 samples per period -- 8.5 samples gave 0.63 of w_l^2
-- while the peak stays right). The least-squares decay is used only when consistent; otherwise the first window's
grid spans the friction widely. An untrusted peak (one short segment at 1 kHz read 374 Hz for a 113 Hz ringing)
stays one candidate among those below, with the least-squares frequency; when it lies below what the segments
resolve (fewer than ``MIN_PERIODS`` periods in the longest) or is the band's lowest bin, the largest local maximum
above that is one too
(``resolved_peak``: a ringing that friction damps within a few periods sits under the segments' slow settling).
When no segment qualifies (a chirp, a log that never lets the motor rest), the spectral peaks of the whole log are
the candidates (``candidates_hz``, ``whole_log_candidates``) that the first window's grid scans: the load's velocity
and its ratio to the torque; for a log without rests (a chirp) first the load's acceleration and that ratio where
both stand above the noise.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.signal import savgol_filter

from ..model.params import DriveParams
from .logs import DriveLog
from .noise import white_noise_std

MIN_SEGMENT_SAMPLES = 32        # a spectrum needs a few samples per period and a few periods
CONSISTENT_W2 = 0.3             # relative disagreement of the two w_l^2 beyond which the start is not trusted
MIN_FREQUENCY_HZ = 2.0          # below this a "ringing" is a drift (the old start's floor, kept)
# A spectral peak is trusted without the least-squares check when it comes from at least MIN_SEGMENTS segments and
# stands MIN_CONTRAST (20 dB) above the band's median power: the largest of ~1000 bins of pure noise reaches ~10x
# the median (an exponential's ln(1000) / ln(2)).
MIN_SEGMENTS = 3
MIN_CONTRAST = 100.0
W2_SPREAD = 0.06    # the smallest relative uncertainty of a trusted w_l^2 that the first grid spans
MIN_PERIODS = 2.0   # ... and when the longest segment spans this many periods of it (else the peak is resolution-bound)


class StartError(RuntimeError):
    """The log holds no motion from which a start can be read."""


def standstill_runs(counts: np.ndarray, min_len: int) -> list[tuple[int, int]]:
    """Runs [start, stop) of at least ``min_len`` samples over which the encoder count does not change."""
    change = np.flatnonzero(np.diff(counts) != 0) + 1
    edges = np.concatenate([[0], change, [counts.size]])
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b - a >= min_len]


def free_ringing_segments(log: DriveLog, base: DriveParams, min_len: int = MIN_SEGMENT_SAMPLES
                          ) -> list[tuple[int, int]]:
    """Runs [start, stop) of a constant encoder count with no torque above f_m inside (see the module docstring)."""
    counts = np.round(log.motor_pos_rad / base.count_rad).astype(np.int64)
    strong = np.abs(log.motor_torque_Nm) > base.f_m
    out = []
    for s, e in standstill_runs(counts, min_len):
        cuts = np.flatnonzero(strong[s:e]) + s
        edges = np.concatenate([[s - 1], cuts, [e]])
        out += [(int(a) + 1, int(b)) for a, b in zip(edges[:-1], edges[1:]) if b - a - 1 >= min_len]
    return out


def segment_spectrum_peak(segments: list[np.ndarray], rate_hz: float, min_hz: float = MIN_FREQUENCY_HZ,
                          local: bool = False) -> tuple[float | None, float]:
    """(frequency [Hz] of the largest peak above ``min_hz`` of the summed power spectra of ``segments`` (each
    detrended, Hann-windowed and zero-padded to a common length; ``local``: the largest local maximum), the
    peak's power over the band's median); (None, 0) when there is nothing to analyse."""
    longest = max((s.size for s in segments), default=0)
    if longest < MIN_SEGMENT_SAMPLES:
        return None, 0.0
    nfft = 1 << int(math.ceil(math.log2(4 * longest)))
    power = np.zeros(nfft // 2 + 1)
    for s in segments:
        t = np.arange(s.size)
        detrended = s - np.polyval(np.polyfit(t, s, 1), t)
        power += np.abs(np.fft.rfft(detrended * np.hanning(s.size), nfft)) ** 2
    freq = np.fft.rfftfreq(nfft, 1.0 / rate_hz)
    peak = _peak(power, freq, min_hz, local)
    band = power[freq > min_hz]
    contrast = float(band.max() / max(np.median(band), 1e-300)) if band.size else 0.0
    return peak, contrast


def _peak(power: np.ndarray, freq: np.ndarray, min_hz: float = MIN_FREQUENCY_HZ, local: bool = False
          ) -> float | None:
    """Frequency of the largest bin above ``min_hz`` (``local``: of the largest local maximum there, so that a
    spectrum falling off from below ``min_hz`` does not give the band's edge), interpolated at a local maximum."""
    band = np.flatnonzero(freq > min_hz)
    if local:
        inner = band[(band > 0) & (band < power.size - 1)]
        band = inner[(power[inner] >= power[inner - 1]) & (power[inner] >= power[inner + 1])]
    if band.size < 3 or not np.any(power[band] > 0):
        return None
    k = int(band[np.argmax(power[band])])
    if 0 < k < power.size - 1:  # parabolic interpolation of the log-spectrum around the peak bin
        a, b, c = np.log(power[k - 1:k + 2] + 1e-300)
        den = a - 2 * b + c
        # only at a local maximum (the vertex then lies within half a bin): at the band's lower edge the bin below
        # (outside the band) can be the larger one, and the vertex then lies anywhere (a 10 s chirp read 0.007 Hz:
        # its first window became the whole log, 104 s)
        shift = 0.5 * (a - c) / den if den < 0 and b >= max(a, c) else 0.0
        return float((k + shift) * (freq[1] - freq[0]))
    return float(freq[k])


def dominant_frequency(segments: list[np.ndarray], rate_hz: float) -> float:
    """Frequency [Hz] of the largest spectral peak above 2 Hz of the (demeaned, concatenated) segments. Kept for
    callers outside the identifier (the identifier uses ``segment_spectrum_peak``)."""
    x = np.concatenate([s - s.mean() for s in segments])
    spec = np.abs(np.fft.rfft(x * np.hanning(x.size)))
    peak = _peak(spec ** 2, np.fft.rfftfreq(x.size, 1.0 / rate_hz))
    return float(peak if peak is not None else 0.0)


def whole_log_candidates(log: DriveLog, count: int = 3, rests: bool = True) -> list[float]:
    """Frequencies [Hz] of the ``count`` largest spectral peaks of the load's velocity and of the ratio of the load's
    acceleration spectrum to the torque's (a resonance shows there even when the torque never rests); for a log
    without rests (``rests`` False: fewer than ``MIN_SEGMENTS`` free-ringing segments, e.g. a chirp), first those
    of the load's acceleration and of the ratio, both only where the load's spectrum stands above its sensor noise
    (``_above_noise``) and the ratio only where the torque has power (``TORQUE_BAND``).

    Why acceleration without rests: the motion of a body driven by a broadband torque falls off as 1/f^2 (velocity),
    so a chirp's slow motion hides the resonance in the velocity spectrum (measured: peaks at 10-16 Hz for a 198 Hz
    mode), while a rigid body's acceleration is flat in the torque and the resonance stands out. Why the bands: the
    sensor's white noise grows as f^4 in acceleration, and a ratio is noise where the torque has no power (the
    chirps' unbanded ratio peaked at 0.7-5 kHz, far above their sweeps). Why not for logs with rests: on pulse
    trains the pulses' own harmonics lead those spectra, and their first windows then started from a scale 20x off
    (one of the suite's pulse trains ended 35 % off); the velocity peaks and the unbanded ratio have served them."""
    y = log.load_pos_rad - np.polyval(np.polyfit(log.time_s, log.load_pos_rad, 1), log.time_s)
    win = np.hanning(y.size)
    freq = np.fft.rfftfreq(y.size, log.dt)
    py_raw = np.abs(np.fft.rfft(y * win)) ** 2
    pu_raw = np.abs(np.fft.rfft((log.motor_torque_Nm - log.motor_torque_Nm.mean()) * win)) ** 2
    py, pu = _smooth(py_raw), _smooth(pu_raw)
    specs = [py_raw * freq ** 2, _smooth(py_raw * freq ** 4) / (pu + 1e-300)]
    if not rests:
        above = _above_noise(py, win, white_noise_std(log.load_pos_rad))
        accel = np.where(above, py * freq ** 4, 0.0)
        specs = [accel, np.where(above & (pu >= TORQUE_BAND * pu.max()), accel / (pu + 1e-300), 0.0), specs[0]]
    out: list[float] = []
    for spec in specs:
        for f in _largest_peaks(spec, freq, count):
            if all(abs(f / g - 1) > 0.05 for g in out):
                out.append(f)
    return out


SMOOTH_BINS = 9           # bins over which the whole log's spectra are averaged (a periodogram's bin is chi^2 with 2
                          # degrees of freedom; 9 bins bring its scatter to +-1/3)
NOISE_CONTRAST = 10.0     # a smoothed bin counts as motion when it holds 10x the sensor noise's power
TORQUE_BAND = 1e-3        # a ratio is read only where the torque's power is within 30 dB of its peak


def _smooth(power: np.ndarray) -> np.ndarray:
    return np.convolve(power, np.ones(SMOOTH_BINS) / SMOOTH_BINS, "same")


def _above_noise(power: np.ndarray, win: np.ndarray, sigma: float) -> np.ndarray:
    """The bins of a smoothed periodogram (window ``win``) that hold ``NOISE_CONTRAST`` x the power of white noise
    of ``sigma`` (sigma^2 x sum(win^2) per bin)."""
    return power > NOISE_CONTRAST * sigma ** 2 * float(np.sum(win ** 2))


def _largest_peaks(spec: np.ndarray, freq: np.ndarray, count: int) -> list[float]:
    """Frequencies [Hz] of the ``count`` largest peaks of ``spec`` above ``MIN_FREQUENCY_HZ``, each next one outside
    5 bins of those before."""
    spec = spec.copy()
    out = []
    for _ in range(count):
        f = _peak(spec, freq)
        if f is None:
            break
        out.append(f)
        k = int(round(f / (freq[1] - freq[0])))
        spec[max(0, k - 5):k + 6] = 0.0
    return out


def _ls_ringing(log: DriveLog, segs: list[tuple[int, int]], f_peak: float, sigma: float
                ) -> tuple[float, float, int, int]:
    """(w_l^2, f_l/J_l, rows, window) by least squares on the segments' free ringing (module docstring)."""
    rate = log.meta.sample_rate_hz
    y = log.load_pos_rad
    window = int(max(7, 2 * round(rate / (16.0 * f_peak)) + 1))  # ~1/8 of a ringing period, odd
    if window >= y.size:
        return math.nan, math.nan, 0, window
    v = savgol_filter(y, window, 3, deriv=1, delta=log.dt)
    a = savgol_filter(y, window, 3, deriv=2, delta=log.dt)
    sigma_v = sigma * math.sqrt(12.0 / (window**3)) / log.dt  # LS slope noise over the window
    # rows within a smoothing window of a stop or reversal are left out: there the friction force jumps and the
    # window smears the jump into the estimated acceleration
    slow = np.abs(v) <= 5 * sigma_v
    near_stop = np.convolve(slow.astype(float), np.ones(2 * window + 1), mode="same") > 0
    xs, ss, ts = [], [], []
    for s, e in segs:
        idx = np.arange(s + window, e - window)
        idx = idx[~near_stop[idx]]
        if idx.size < 3:
            continue
        # demeaned within the segment: the segment's own equilibrium (r q_m + friction side) drops out
        xs.append(-(y[idx] - y[idx].mean()))
        ss.append(-(np.sign(v[idx]) - np.sign(v[idx]).mean()))
        ts.append(a[idx] - a[idx].mean())
    rows = sum(x.size for x in xs)
    if rows < 50:
        return math.nan, math.nan, rows, window
    X = np.column_stack([np.concatenate(xs), np.concatenate(ss)])
    coef, *_ = np.linalg.lstsq(X, np.concatenate(ts), rcond=None)
    return float(coef[0]), float(coef[1]), rows, window


def _verdicts(segs: list[tuple[int, int]], f_peak: float | None, contrast: float, w2_ls: float,
              resolved: float | None) -> tuple[bool, bool]:
    """(consistent, trusted): the spectral and least-squares frequencies agree; the spectral peak can be trusted
    (clear of the noise, and either consistent or a peak the segments resolve, ``resolved`` None, in
    ``MIN_SEGMENTS`` segments)."""
    consistent = (f_peak is not None and w2_ls > 0 and
                  abs(w2_ls / (2 * math.pi * f_peak) ** 2 - 1) <= CONSISTENT_W2)
    trusted = f_peak is not None and contrast >= MIN_CONTRAST and (consistent or (resolved is None and
                                                                              len(segs) >= MIN_SEGMENTS))
    return consistent, trusted


def resolved_peak(segments: list[np.ndarray], rate_hz: float, f_peak: float | None) -> float | None:
    """The segments' largest spectral peak (a local maximum) among the frequencies whose ``MIN_PERIODS`` periods
    fit in the longest segment, when it is not their overall peak (else None): the overall peak lies below those,
    or it is no local maximum but the band's lowest bin, on a spectrum still rising towards the drift below
    ``MIN_FREQUENCY_HZ``.

    A segment's slow motion (the load settling to a new rest while the motor is stuck, the motor creeping within a
    count) puts its power at a cycle or so per segment, above a ringing that friction damps within a few periods:
    measured on an independent drive's 10 s log (36 segments of 0.2-0.3 s), the overall peak was 2.4 Hz and the
    ringing's 484.6 Hz (truth 484.5 Hz) the fifth-largest bin, at 395x the median power; without it among the
    candidates the fit ended trapped at 20x the stiffness, 140x the noise. On another drive's PD-step log (18
    segments, the longest 0.99 s) the overall peak was the band's lowest bin, 2.14 Hz: 2.1 periods in the longest
    segment, it passed as resolved and was trusted alone, and the fit ended at 18000x the noise; the largest local
    maximum is the ringing, 137.5 Hz (truth 138.5 Hz)."""
    longest = max((x.size for x in segments), default=0) / rate_hz
    if f_peak is None or longest <= 0:
        return None
    found = segment_spectrum_peak(segments, rate_hz, max(MIN_FREQUENCY_HZ, MIN_PERIODS / longest), local=True)[0]
    return None if found == f_peak else found


def _candidates(log: DriveLog, f_peak: float | None, w2_ls: float, trusted: bool, segments: int,
                resolved: float | None = None) -> list[float]:
    """Frequencies [Hz] for the first window: the trusted peak alone; else the segments' own estimates (the peak,
    the peak of what the segments resolve: ``resolved_peak``, the least-squares frequency), then the whole log's
    peaks (``segments``: the free-ringing segments found). ``StartError`` when there is none (the load never
    rings)."""
    own = [f_peak] if f_peak is not None else []
    if not trusted and resolved is not None:
        own.append(resolved)
    if not trusted and w2_ls > 0:
        own.append(math.sqrt(w2_ls) / (2 * math.pi))
    candidates = [f_peak] if trusted else own + whole_log_candidates(log, rests=segments >= MIN_SEGMENTS)
    if not candidates:
        raise StartError("the load shows no ringing: neither free ringing while the motor rests nor a resonance "
                         "in the whole log; K*, J_l* and f_l* are not excited (apply pulses and let the load ring)")
    return candidates


def equation_error_start(log: DriveLog, base: DriveParams) -> dict[str, float]:
    """w_l^2 = K_s/J_l and f_l/J_l from the load's free ringing (see the module docstring). Keys: ``w_l2``,
    ``f_l_over_J_l``, ``f_peak_hz``, ``w_l2_ls``, ``segments``, ``rows``, ``window``, ``consistent`` (1.0 when the
    spectral and least-squares frequencies agree), ``candidates_hz`` (frequencies the first window's grid scans)."""
    rate = log.meta.sample_rate_hz
    y = log.load_pos_rad
    sigma = max(white_noise_std(y), 1e-15)
    segs = free_ringing_segments(log, base)
    pieces = [y[s:e] for s, e in segs]
    f_peak, contrast = segment_spectrum_peak(pieces, rate) if segs else (None, 0.0)
    out: dict[str, float] = {"segments": len(segs), "sigma_start_rad": sigma, "peak_contrast": contrast}
    w2_ls = f_over_J = math.nan
    rows, window = 0, 0
    if f_peak is not None:
        w2_ls, f_over_J, rows, window = _ls_ringing(log, segs, f_peak, sigma)
    resolved = resolved_peak(pieces, rate, f_peak)
    consistent, trusted = _verdicts(segs, f_peak, contrast, w2_ls, resolved)
    # how far the frequency may be off: the two estimates' disagreement (w_l^2), at least 6 % (+-3 % in w_l)
    spread = abs(w2_ls / (2 * math.pi * f_peak) ** 2 - 1) if consistent else 0.0
    candidates = _candidates(log, f_peak, w2_ls, trusted, len(segs), resolved)
    f0 = candidates[0]
    out.update(w_l2=(2 * math.pi * f0) ** 2, w_l2_ls=w2_ls, f_peak_hz=f0,
               f_l_over_J_l=f_over_J if consistent and f_over_J > 0 else math.nan,
               rows=rows, window=window, consistent=float(consistent), frequency_trusted=float(trusted),
               w_l2_spread=max(W2_SPREAD, spread),
               candidates_hz=candidates)
    return out
