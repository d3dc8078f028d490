"""Non-parametric frequency responses of a torque-commanded chirp (section II.B).

Two estimates of the command-to-torque response of eq (4) are computed from a
recorded chirp, without any parametric model:

* **H1 with uncertainty.** ``H1 = Puy / Puu`` from Welch cross-spectra (Hann
  window, 50 % overlap). Segments resolve a quarter of the sweep's start
  frequency ``f0`` at low frequencies; where the bands are wide enough,
  four-times shorter segments give more averages and lose less of a sweep's
  end to the window. The Welch bins are pooled into bands of a log-spaced
  grid over ``[f0, f1]``; pooling sums the spectra, so a band's H1 is the
  ``Puu``-weighted mean of the true response over its bins (with an
  optional reference delay taken out first, so that the delay's phase turn
  across a band does not count as lost coherence). With the
  pooled coherence ``gamma^2`` and the effective number of independent
  spectral terms ``n`` the standard errors are (Bendat & Piersol)::

      std(|H|) / |H| = std(arg H) = sqrt((1 - gamma^2) / (2 n gamma^2))

  which follows from ``Var(H1) = sigma_N^2 / sum(Puu)`` for output noise
  ``sigma_N`` uncorrelated with the input.

* **Exponential-sweep deconvolution** (Farina; Novak et al.). The measured
  output is deconvolved by the known sweep ``x(t) = A sin(2 pi f0 L
  (exp(t / L) - 1))`` (``L`` = ``sweep_rate_s``). The k-th harmonic of a
  nonlinear response appears ``L ln k`` *before* the linear impulse response,
  so windows around ``-L ln k`` separate the harmonic responses. The spectrum
  of harmonic window k at output frequency ``k f`` is the amplitude of the
  k-th harmonic per unit input amplitude at input frequency ``f``. From these
  the share of the output power that is not linear (harmonics 2..K versus 1)
  is reported per octave band of the input frequency.

Nothing here reads ground truth; everything comes from the recorded signals
and the ``/experiment`` attributes of a dataset.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from iiwa_ident.errors import IiwaIdentError
from iiwa_ident.references import exponential_sweep

__all__ = [
    "CrossSpectra",
    "FRFEstimate",
    "HarmonicResponses",
    "NonlinearBand",
    "welch_segment_length",
    "cross_spectra",
    "multi_resolution_spectra",
    "log_bands",
    "octave_bands",
    "h1_estimate",
    "sweep_signal",
    "ess_harmonics",
    "nonlinear_share",
]

# Correlations of Hann-windowed DFT coefficients of white noise: between
# adjacent bins (-2/3 in amplitude), bins two apart (1/6), and between
# segments overlapping by half (1/6). They reduce the number of independent
# terms a pooled estimate averages over.
_HANN_BIN_CORR = (2.0 / 3.0, 1.0 / 6.0)
_HANN_HALF_OVERLAP_CORR = 1.0 / 6.0


# --------------------------------------------------------------------------
# Welch cross-spectra


@dataclass(kw_only=True)
class CrossSpectra:
    """Welch auto- and cross-spectra of one input and one or more outputs.

    Attributes
    ----------
    f_hz : numpy.ndarray
        Bin frequencies [Hz], ``0 .. fs/2``.
    puu : numpy.ndarray
        Input auto-spectrum summed over segments [U^2 / Hz] (unnormalised
        scale is irrelevant for ratios).
    pyy : numpy.ndarray
        Output auto-spectra, shape ``(n_outputs, n_bins)``.
    puy : numpy.ndarray
        Cross-spectra ``conj(U) Y``, shape ``(n_outputs, n_bins)``.
    n_segments : int
        Number of Welch segments.
    nperseg : int
        Segment length [samples].
    fs : float
        Sample rate [Hz].
    """

    f_hz: np.ndarray
    puu: np.ndarray
    pyy: np.ndarray
    puy: np.ndarray
    n_segments: int
    nperseg: int
    fs: float


def welch_segment_length(n_samples: int, fs: float, f0_hz: float) -> int:
    """Segment length resolving a quarter of ``f0_hz`` (a power of two, at most ``n_samples``).

    Parameters
    ----------
    n_samples : int
        Record length [samples].
    fs : float
        Sample rate [Hz].
    f0_hz : float
        Lowest frequency of interest [Hz] (the sweep's start frequency).

    Returns
    -------
    int
        Segment length [samples]; the bin spacing ``fs / nperseg`` is at most
        ``f0_hz / 4`` unless the record is shorter than that.
    """
    want = 4.0 * fs / max(f0_hz, 1e-9)
    nper = 1 << int(math.ceil(math.log2(max(want, 16.0))))
    return int(min(nper, n_samples))


def cross_spectra(u: np.ndarray, ys: np.ndarray, fs: float, nperseg: int) -> CrossSpectra:
    """Welch spectra with a Hann window and segments tiling the whole record.

    Segments overlap by about half; their starts are spread evenly so the
    first begins at the first sample and the last ends at the last sample (a
    sweep's highest frequencies sit at the very end of the record, which the
    usual fixed-hop layout would drop). Each segment's mean is removed.

    Parameters
    ----------
    u : numpy.ndarray
        Input samples, shape ``(n,)``.
    ys : numpy.ndarray
        Output samples, shape ``(n,)`` or ``(n_outputs, n)``.
    fs : float
        Sample rate [Hz].
    nperseg : int
        Segment length [samples], at most ``n``.

    Returns
    -------
    CrossSpectra
    """
    u = np.asarray(u, float)
    ys = np.atleast_2d(np.asarray(ys, float))
    n = u.shape[0]
    if ys.shape[1] != n:
        raise ValueError("input and outputs must have the same length")
    nperseg = int(min(nperseg, n))
    if nperseg < 8:
        raise IiwaIdentError(f"too few samples for a spectrum ({n})")
    hop = nperseg // 2
    n_seg = 1 if n == nperseg else int(math.ceil((n - nperseg) / hop)) + 1
    starts = np.round(np.linspace(0, n - nperseg, n_seg)).astype(int)
    win = np.hanning(nperseg + 2)[1:-1]  # symmetric Hann without the zero end points
    idx = starts[:, None] + np.arange(nperseg)[None, :]
    useg = u[idx]
    U = np.fft.rfft((useg - useg.mean(axis=1, keepdims=True)) * win, axis=1)
    puu = np.sum(np.abs(U) ** 2, axis=0)
    pyy, puy = [], []
    for y in ys:
        yseg = y[idx]
        Y = np.fft.rfft((yseg - yseg.mean(axis=1, keepdims=True)) * win, axis=1)
        pyy.append(np.sum(np.abs(Y) ** 2, axis=0))
        puy.append(np.sum(np.conj(U) * Y, axis=0))
    f = np.fft.rfftfreq(nperseg, 1.0 / fs)
    return CrossSpectra(f_hz=f, puu=puu, pyy=np.array(pyy), puy=np.array(puy), n_segments=n_seg, nperseg=nperseg,
                        fs=float(fs))


def _effective_terms(n_bins: int, n_segments: int) -> float:
    """Independent spectral terms in a pool of adjacent Hann bins over overlapping segments."""
    m = float(n_bins)
    r1, r2 = _HANN_BIN_CORR
    bin_factor = 1.0 + 2.0 * r1**2 * max(m - 1, 0) / m + 2.0 * r2**2 * max(m - 2, 0) / m
    k = float(n_segments)
    seg_factor = 1.0 + 2.0 * _HANN_HALF_OVERLAP_CORR**2 * max(k - 1, 0) / k
    return m * k / (bin_factor * seg_factor)


# --------------------------------------------------------------------------
# frequency grids


def log_bands(f_lo_hz: float, f_hi_hz: float, per_octave: int = 12) -> np.ndarray:
    """Edges of log-spaced bands covering ``[f_lo_hz, f_hi_hz]`` [Hz].

    Returns
    -------
    numpy.ndarray
        Band edges [Hz], increasing, first ``f_lo_hz`` and last ``f_hi_hz``.
    """
    if not 0 < f_lo_hz < f_hi_hz:
        raise ValueError(f"need 0 < f_lo < f_hi, got {f_lo_hz}, {f_hi_hz}")
    n = max(1, int(math.ceil(per_octave * math.log2(f_hi_hz / f_lo_hz) - 1e-9)))
    return np.geomspace(f_lo_hz, f_hi_hz, n + 1)


def octave_bands(f_lo_hz: float, f_hi_hz: float) -> list[tuple[float, float]]:
    """Octave bands ``[f_lo 2^i, f_lo 2^(i+1))`` covering ``[f_lo_hz, f_hi_hz]``, the last one clipped."""
    bands: list[tuple[float, float]] = []
    lo = f_lo_hz
    while lo < f_hi_hz * (1 - 1e-9):
        hi = min(2.0 * lo, f_hi_hz)
        if hi / lo < 1.2 and bands:  # fold a sliver into the previous band
            bands[-1] = (bands[-1][0], hi)
        else:
            bands.append((lo, hi))
        lo = hi
    return bands


# --------------------------------------------------------------------------
# H1 on a log grid


@dataclass(kw_only=True)
class FRFEstimate:
    """H1 estimate pooled on log-spaced bands, with its uncertainty.

    Attributes
    ----------
    f_hz : numpy.ndarray
        Band centres (geometric mean of the edges) [Hz].
    lo_hz, hi_hz : numpy.ndarray
        Band edges [Hz].
    f_mean_hz : numpy.ndarray
        ``Puu``-weighted mean bin frequency of each band [Hz].
    H : numpy.ndarray
        Complex response (output unit per input unit).
    coherence : numpy.ndarray
        Pooled magnitude-squared coherence, 0..1.
    std_mag : numpy.ndarray
        Standard deviation of ``|H|`` (same unit as ``|H|``).
    std_phase_rad : numpy.ndarray
        Standard deviation of ``arg H`` [rad].
    n_terms : numpy.ndarray
        Effective number of independent spectral terms pooled per band.
    bin_f_hz, bin_weight : numpy.ndarray
        Frequencies [Hz] and ``Puu`` weights of the pooled bins.
    bin_band : numpy.ndarray
        Band index of each pooled bin.
    delay_s : float
        Reference delay [s] removed from each bin before pooling and put
        back at :attr:`f_mean_hz` afterwards (see :func:`h1_estimate`).
    """

    f_hz: np.ndarray
    lo_hz: np.ndarray
    hi_hz: np.ndarray
    f_mean_hz: np.ndarray
    H: np.ndarray
    coherence: np.ndarray
    std_mag: np.ndarray
    std_phase_rad: np.ndarray
    n_terms: np.ndarray
    bin_f_hz: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    bin_weight: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    bin_band: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, int))
    delay_s: float = 0.0

    @property
    def std_complex(self) -> np.ndarray:
        """Standard deviation of the complex estimate, ``sqrt(E|H1 - H|^2)``."""
        return math.sqrt(2.0) * self.std_mag

    def band_average(self, response: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """Average a model response over each band exactly as H1 pools it.

        Parameters
        ----------
        response : callable
            Maps bin frequencies [Hz] to complex responses.

        Returns
        -------
        numpy.ndarray
            ``sum(Puu_i H(f_i) r_i) / sum(Puu_i) / r(f_mean)`` per band, with
            ``r = exp(j 2 pi f delay_s)``, comparable with :attr:`H`.
        """
        rot = np.exp(2j * np.pi * self.bin_f_hz * self.delay_s)
        h = np.asarray(response(self.bin_f_hz), complex) * rot * self.bin_weight
        nb = len(self.f_hz)
        num = np.bincount(self.bin_band, weights=h.real, minlength=nb) + 1j * np.bincount(
            self.bin_band, weights=h.imag, minlength=nb)
        den = np.bincount(self.bin_band, weights=self.bin_weight, minlength=nb)
        return num / den * np.exp(-2j * np.pi * self.f_mean_hz * self.delay_s)

    def select(self, mask: np.ndarray) -> FRFEstimate:
        """The estimate restricted to the bands where ``mask`` is true."""
        mask = np.asarray(mask, bool)
        new_index = -np.ones(len(mask), int)
        new_index[mask] = np.arange(int(mask.sum()))
        keep = mask[self.bin_band]
        return FRFEstimate(f_hz=self.f_hz[mask], lo_hz=self.lo_hz[mask], hi_hz=self.hi_hz[mask],
                           f_mean_hz=self.f_mean_hz[mask], H=self.H[mask], coherence=self.coherence[mask],
                           std_mag=self.std_mag[mask], std_phase_rad=self.std_phase_rad[mask],
                           n_terms=self.n_terms[mask], bin_f_hz=self.bin_f_hz[keep], bin_weight=self.bin_weight[keep],
                           bin_band=new_index[self.bin_band[keep]], delay_s=self.delay_s)


def multi_resolution_spectra(u: np.ndarray, ys: np.ndarray, fs: float, f_lo_hz: float,
                             shortest: int = 2048) -> list[CrossSpectra]:
    """Welch spectra at several segment lengths, longest first.

    The longest resolves ``f_lo_hz / 4`` (:func:`welch_segment_length`);
    each next one is four times shorter, down to ``shortest`` samples. Short
    segments average more and lose less of a sweep's end to the window, so
    :func:`h1_estimate` uses the shortest one that still puts several bins
    into a band.
    """
    n = len(u)
    nper = welch_segment_length(n, fs, f_lo_hz)
    out = [cross_spectra(u, ys, fs, nper)]
    while nper // 4 >= shortest:
        nper //= 4
        out.append(cross_spectra(u, ys, fs, nper))
    return out


def h1_estimate(u: np.ndarray | None, y: np.ndarray | None, fs: float, f_lo_hz: float, f_hi_hz: float, *,
                nperseg: int | None = None, per_octave: int = 12,
                spectra: CrossSpectra | list[CrossSpectra] | None = None, output: int = 0,
                bins_per_band: int = 3, delay_s: float = 0.0) -> FRFEstimate:
    """H1 from input ``u`` to output ``y`` on log-spaced bands over ``[f_lo_hz, f_hi_hz]``.

    Parameters
    ----------
    u, y : numpy.ndarray
        Input and output samples (e.g. ``tau_c`` and ``tau_j`` [Nm]).
    fs : float
        Sample rate [Hz].
    f_lo_hz, f_hi_hz : float
        Frequency range [Hz] (the sweep's ``f0`` and ``f1``).
    nperseg : int, optional
        One Welch segment length [samples]; default: several lengths
        (:func:`multi_resolution_spectra`).
    per_octave : int
        Bands per octave.
    spectra : CrossSpectra or list of CrossSpectra, optional
        Precomputed spectra (then ``u``, ``y`` are ignored).
    output : int
        Which output of ``spectra`` to use.
    bins_per_band : int
        With several resolutions, each band takes the coarsest one that
        still has this many bins in the band (else the finest).
    delay_s : float
        Reference delay [s]. A delay turns the phase across a band, and
        pooling turning phasors loses magnitude and coherence that no noise
        caused (0.5 % and 1 % for 5 ms over a twelfth of an octave at
        200 Hz). The bins are pooled with this delay taken out; the band's
        result gets it back at its mean frequency.

    Returns
    -------
    FRFEstimate
        Bands holding at least one Welch bin; bands narrower than the bin
        spacing at low frequency are merged into their neighbours.
    """
    if spectra is None:
        if u is None or y is None:
            raise ValueError("h1_estimate needs the samples u and y or their spectra")
        if nperseg is None:
            spectra = multi_resolution_spectra(u, y, fs, f_lo_hz)
        else:
            spectra = cross_spectra(u, y, fs, nperseg)
    if isinstance(spectra, CrossSpectra):
        spectra = [spectra]
    spectra = sorted(spectra, key=lambda sp: -sp.nperseg)  # finest resolution first
    fs = spectra[0].fs
    edges = log_bands(f_lo_hz, min(f_hi_hz, 0.5 * fs), per_octave)
    width = np.diff(edges)
    # Resolution per band: the coarsest spectrum with enough bins, else the finest.
    choice = np.zeros(len(width), int)
    for j, sp in enumerate(spectra):
        choice[width >= bins_per_band * sp.fs / sp.nperseg] = j
    pieces = []  # (band, f, puu, pyy, puy, n_segments) per bin
    for j, sp in enumerate(spectra):
        f = sp.f_hz
        band = np.searchsorted(edges, f, side="right") - 1
        inside = (band >= 0) & (band < len(width)) & (f > 0)
        inside &= choice[np.clip(band, 0, len(width) - 1)] == j
        pieces.append((band[inside], f[inside], sp.puu[inside], sp.pyy[output][inside], sp.puy[output][inside],
                       np.full(int(inside.sum()), sp.n_segments)))
    band, f_in, puu, pyy, puy, nseg = (np.concatenate(z) for z in zip(*pieces))
    order = np.argsort(f_in, kind="stable")
    band, f_in, puu, pyy, puy, nseg = band[order], f_in[order], puu[order], pyy[order], puy[order], nseg[order]
    puy = puy * np.exp(2j * np.pi * f_in * delay_s)
    used = np.unique(band)
    # Renumber so that empty bands (narrower than a bin) vanish.
    renum = np.searchsorted(used, band)
    nb = len(used)
    s_uu = np.bincount(renum, weights=puu, minlength=nb)
    s_yy = np.bincount(renum, weights=pyy, minlength=nb)
    s_uy = np.bincount(renum, weights=puy.real, minlength=nb) + 1j * np.bincount(renum, weights=puy.imag, minlength=nb)
    counts = np.bincount(renum, minlength=nb)
    segs = np.bincount(renum, weights=nseg, minlength=nb) / np.maximum(counts, 1)
    lo = edges[used]
    # An empty band's range goes to the used band below it.
    hi = np.append(lo[1:], edges[-1])
    with np.errstate(divide="ignore", invalid="ignore"):
        f_mean = np.bincount(renum, weights=puu * f_in, minlength=nb) / s_uu
        H = s_uy / s_uu * np.exp(-2j * np.pi * f_mean * delay_s)
        coh = np.clip(np.abs(s_uy) ** 2 / (s_uu * s_yy), 0.0, 1.0)
        n_terms = np.array([_effective_terms(int(c), int(round(k))) for c, k in zip(counts, segs)])
        rel = np.sqrt((1.0 - coh) / (2.0 * n_terms * coh))
    rel = np.where(np.isfinite(rel), rel, np.inf)
    return FRFEstimate(
        f_hz=np.sqrt(lo * hi), lo_hz=lo, hi_hz=hi, f_mean_hz=f_mean, H=H, coherence=coh,
        std_mag=rel * np.abs(H), std_phase_rad=np.minimum(rel, math.pi), n_terms=n_terms,
        bin_f_hz=f_in, bin_weight=puu, bin_band=renum, delay_s=float(delay_s),
    )


# --------------------------------------------------------------------------
# exponential sine sweep deconvolution


def sweep_signal(n: int, fs: float, f0_hz: float, f1_hz: float, duration_s: float,
                 amplitude: float = 1.0) -> np.ndarray:
    """The exponential sweep ``A sin(2 pi f0 L (exp(t/L) - 1))`` at ``t = k / fs`` for ``t < duration_s``.

    Samples after the sweep's end are zero (:func:`iiwa_ident.references.exponential_sweep`).
    """
    t = np.arange(n) / fs
    x = amplitude * exponential_sweep(t, f0_hz, f1_hz, duration_s)
    x[t >= duration_s] = 0.0
    return x


@dataclass(kw_only=True)
class HarmonicResponses:
    """Harmonic frequency responses of an exponential sweep.

    Attributes
    ----------
    f_hz : numpy.ndarray
        Frequency axis of the responses [Hz] (output frequency).
    H : numpy.ndarray
        ``H[k-1]`` is the spectrum of the k-th harmonic impulse response,
        complex, shape ``(n_harmonics, n_freq)``; at output frequency ``F``
        it is the output amplitude of harmonic k per unit input amplitude
        at input frequency ``F / k``.
    noise : numpy.ndarray
        Power spectrum of an equally long window without any response
        (the deconvolved measurement noise), shape ``(n_harmonics, n_freq)``.
    valid : numpy.ndarray
        Where the sweep has energy (``f0 <= F <= f1``), boolean ``(n_freq,)``.
    amplitude : float
        Sweep amplitude A.
    f0_hz, f1_hz, sweep_rate_s : float
        Sweep parameters [Hz, Hz, s].
    delays_s : numpy.ndarray
        Where harmonic k sits relative to the linear response, ``-L ln k`` [s].
    """

    f_hz: np.ndarray
    H: np.ndarray
    noise: np.ndarray
    valid: np.ndarray
    amplitude: float
    f0_hz: float
    f1_hz: float
    sweep_rate_s: float
    delays_s: np.ndarray

    @property
    def n_harmonics(self) -> int:
        return self.H.shape[0]

    def at_input(self, k: int, f_in_hz: np.ndarray) -> np.ndarray:
        """Harmonic k's response (per unit input amplitude) at input frequencies ``f_in_hz``.

        Returns NaN where ``k f`` lies outside the swept band.
        """
        F = k * np.asarray(f_in_hz, float)
        Hk = self.H[k - 1]
        out = np.interp(F, self.f_hz, Hk.real) + 1j * np.interp(F, self.f_hz, Hk.imag)
        ok = (F >= self.f0_hz) & (F <= self.f1_hz)
        return np.where(ok, out, np.nan)

    def power_at_input(self, k: int, f_in_hz: np.ndarray) -> np.ndarray:
        """Output power of harmonic k per unit input power, noise floor removed (NaN outside the band)."""
        F = k * np.asarray(f_in_hz, float)
        p = np.interp(F, self.f_hz, np.abs(self.H[k - 1]) ** 2) - np.interp(F, self.f_hz, self.noise[k - 1])
        ok = (F >= self.f0_hz) & (F <= self.f1_hz)
        return np.where(ok, np.maximum(p, 0.0), np.nan)


def _taper(n: int, ramp: int) -> np.ndarray:
    """A window of ``n`` ones with half-Hann ramps of ``ramp`` samples at both ends."""
    w = np.ones(n)
    ramp = int(min(ramp, n // 2))
    if ramp > 0:
        r = 0.5 - 0.5 * np.cos(np.pi * (np.arange(ramp) + 0.5) / ramp)
        w[:ramp] = r
        w[n - ramp:] = r[::-1]
    return w


def ess_harmonics(y: np.ndarray, fs: float, f0_hz: float, f1_hz: float, duration_s: float, amplitude: float, *,
                  n_harmonics: int = 5, sweep: np.ndarray | None = None) -> HarmonicResponses:
    """Deconvolve a sweep response and separate its harmonic impulse responses.

    Parameters
    ----------
    y : numpy.ndarray
        Measured output, starting with the sweep (e.g. ``tau_j`` [Nm]).
    fs : float
        Sample rate [Hz].
    f0_hz, f1_hz, duration_s, amplitude : float
        The sweep's start and end frequency [Hz], duration [s] and amplitude
        (the ``/experiment`` attributes of a chirp dataset).
    n_harmonics : int
        Harmonics to separate (1 = linear response).
    sweep : numpy.ndarray, optional
        The excitation itself; default :func:`sweep_signal`.

    Returns
    -------
    HarmonicResponses

    Notes
    -----
    Deconvolution is done in the frequency domain with a regularised inverse
    of the sweep's spectrum, restricted to ``[f0, f1]``. Harmonic k's window
    starts a quarter of the gap to harmonic k+1 before ``-L ln k`` and ends
    where harmonic k-1's window starts, with half-Hann tapers; the linear
    window ends ``L ln 2`` after zero. The noise floor comes from an equally
    long window at positive lags beyond the linear response.
    """
    y = np.asarray(y, float)
    n = len(y)
    L = duration_s / math.log(f1_hz / f0_hz)
    if sweep is None:
        sweep = sweep_signal(n, fs, f0_hz, f1_hz, duration_s, amplitude)
    sweep = np.asarray(sweep, float)
    span = max(n, len(sweep))
    N = 1 << int(math.ceil(math.log2(2 * span)))
    X = np.fft.rfft(sweep, N)
    Y = np.fft.rfft(y - y.mean(), N)
    F = np.fft.rfftfreq(N, 1.0 / fs)
    inband = (F >= f0_hz) & (F <= f1_hz)
    px = np.abs(X) ** 2
    reg = 1e-6 * px[inband].max() if inband.any() else 1.0
    inv = np.where(inband, np.conj(X) / (px + reg), 0.0)
    h = np.fft.irfft(Y * inv, N)  # circular: negative lags wrap to the end

    centres = -L * np.log(np.arange(1, n_harmonics + 2))  # one extra to bound the last window
    gaps = L * np.log(np.arange(2, n_harmonics + 3) / np.arange(1, n_harmonics + 2))  # c_k - c_{k+1}
    starts = centres[:n_harmonics + 1] - 0.25 * gaps[:n_harmonics + 1]
    ends = np.concatenate([[L * math.log(2.0)], starts[:n_harmonics - 1]])
    starts = starts[:n_harmonics]
    # Deconvolved noise recorded at output frequency F spreads over the lags
    # [-t_F, duration - t_F], t_F = L ln(F / f0) being when the sweep passes F.
    # Two signal-free windows cover it: after the linear response (low F) and
    # beyond the harmonics 2K (high F).
    t_F = L * np.log(np.maximum(F, f0_hz) / f0_hz)
    pos0 = ends[0] + 0.05 * L
    neg_end = -L * math.log(2 * n_harmonics)
    out, noise = [], []
    for k in range(n_harmonics):
        i0 = int(round(starts[k] * fs))
        i1 = int(round(ends[k] * fs))
        m = max(i1 - i0, 8)
        w = _taper(m, max(1, m // 10))
        seg = h[np.mod(i0 + np.arange(m), N)] * w
        # Place the window at its own lag so the spectrum's phase refers to -L ln k.
        buf = np.zeros(N)
        buf[np.mod(np.arange(m) + int(round((starts[k] - centres[k]) * fs)), N)] = seg
        out.append(np.fft.rfft(buf))
        length = m / fs
        floor = np.zeros_like(F)
        count = np.zeros_like(F)
        for lag0, valid in ((pos0, t_F <= duration_s - pos0 - length),
                            (neg_end - length, t_F >= -(neg_end - length))):
            j0 = int(round(lag0 * fs))
            nseg = h[np.mod(j0 + np.arange(m), N)] * w
            floor += np.where(valid, np.abs(np.fft.rfft(nseg, N)) ** 2, 0.0)
            count += valid
        noise.append(floor / np.maximum(count, 1))
    return HarmonicResponses(f_hz=F, H=np.array(out), noise=np.array(noise), valid=inband, amplitude=float(amplitude),
                             f0_hz=float(f0_hz), f1_hz=float(f1_hz), sweep_rate_s=float(L),
                             delays_s=centres[:n_harmonics])


@dataclass
class NonlinearBand:
    """Share of the output power that is not linear, in one octave band of the input frequency.

    Attributes
    ----------
    lo_hz, hi_hz : float
        Input-frequency band [Hz].
    share : float
        ``sum_{k>=2} P_k / sum_{k>=1} P_k`` over the measurable harmonics, 0..1
        (NaN when only the linear response is measurable).
    harmonic_share : list of float
        ``P_k / sum_j P_j`` for k = 1 .. n_harmonics (NaN where ``k f`` is
        outside the sweep).
    harmonics : list of int
        The harmonics that could be measured in this band.
    """

    lo_hz: float
    hi_hz: float
    share: float
    harmonic_share: list[float]
    harmonics: list[int]


def nonlinear_share(harm: HarmonicResponses, bands: list[tuple[float, float]] | None = None,
                    points_per_band: int = 64) -> list[NonlinearBand]:
    """Share of output power in harmonics 2..K versus 1, per input-frequency band.

    Parameters
    ----------
    harm : HarmonicResponses
        From :func:`ess_harmonics`.
    bands : list of (float, float), optional
        Input-frequency bands [Hz]; default the octaves of ``[f0, f1]``.
    points_per_band : int
        Log-spaced input frequencies averaged per band.

    Returns
    -------
    list of NonlinearBand
        A harmonic k counts in a band only where ``k f`` stays within
        ``[f0, f1]`` over the whole band, so all bands compare like with like.
    """
    bands = bands or octave_bands(harm.f0_hz, harm.f1_hz)
    result = []
    for lo, hi in bands:
        f = np.geomspace(lo, hi, points_per_band)
        powers = []
        ks = []
        for k in range(1, harm.n_harmonics + 1):
            p = harm.power_at_input(k, f)
            if np.all(np.isfinite(p)):
                powers.append(float(np.mean(p)))
                ks.append(k)
            else:
                powers.append(math.nan)
        total = float(np.nansum(powers))
        if total <= 0 or not ks:
            shares = [math.nan] * harm.n_harmonics
            share = math.nan
        else:
            shares = [p / total if math.isfinite(p) else math.nan for p in powers]
            share = math.nan if ks == [1] else float(np.nansum(shares[1:]))
        result.append(NonlinearBand(float(lo), float(hi), share, shares, ks))
    return result


def levy_fit(G: np.ndarray, s: np.ndarray, iterations: int = 6) -> tuple[np.ndarray, float] | None:
    """Sanathanan-Koerner (iterated Levy) fit of ``(a s + b0) / (s^2 + a s + a0)`` to ``G``; returns ((a, b0, a0), rel. error)."""
    weight = 1.0 / np.abs(G * s**2)
    x = np.zeros(3)
    for _ in range(max(iterations, 1)):
        # a s (1 - G) + b0 - a0 G = G s^2, weighted towards the relative error of G.
        M = np.column_stack([s * (1 - G), np.ones_like(G), -G]) * weight[:, None]
        rhs = G * s**2 * weight
        Mr = np.vstack([M.real, M.imag])
        rr = np.concatenate([rhs.real, rhs.imag])
        x, *_ = np.linalg.lstsq(Mr, rr, rcond=None)
        a, b0, a0 = x
        den = s**2 + a * s + a0
        weight = 1.0 / np.maximum(np.abs(den * G), 1e-300)
    a, b0, a0 = x
    if a <= 0 or b0 <= 0 or a0 <= b0:
        return None
    model = (a * s + b0) / (s**2 + a * s + a0)
    return x, float(np.sqrt(np.mean(np.abs(model / G - 1) ** 2)))
