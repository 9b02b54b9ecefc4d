"""DS-CDMA RTS/ACK ranging hand-shake: spreading codes and the master's received baseband.

The master sends an RTS at time 0; each of the other nodes synchronises to the first
arrival of the RTS through the (reciprocal) channel, waits a known turnaround delay and
answers with an ACK spread by its own code. All ACKs arrive at once: the master's complex
baseband over the search window is the sum of every ACK through its multipath channel plus
white Gaussian noise. Near-far effects therefore follow from the geometry (path loss,
shadowing by buildings).

Choices the paper leaves open (documented in :class:`CDMAConfig`): Gold codes of length
2^n - 1 (n = 7: 127 chips, preferred pair x^7 + x^3 + 1, x^7 + x^3 + x^2 + x + 1), a
rectangular chip pulse sampled ``samples_per_chip`` times per chip, one code period per ACK
preamble, independent uniform phases of every path in every ACK set (small-scale fading
from sub-wavelength motion between hand-shakes) and a Gaussian turnaround jitter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.channel import compiled
from radioloc.core.backend import check_backend
from radioloc.core.errors import ConfigError, InputError
from radioloc.core.validation import check_positive

#: Boltzmann constant [J/K].
K_BOLTZMANN = 1.380649e-23

#: Feedback taps (exponents below the degree) of preferred pairs of m-sequence polynomials.
PREFERRED_PAIRS = {
    5: ((2,), (4, 3, 2)),
    6: ((1,), (5, 2, 1)),
    7: ((3,), (3, 2, 1)),
    9: ((4,), (6, 4, 3)),
    10: ((3,), (8, 3, 2)),
}


def m_sequence(degree: int, taps: tuple[int, ...]) -> np.ndarray:
    """Binary m-sequence of ``x^degree + sum x^t + 1`` (period ``2^degree - 1``).

    Recurrence ``a[k + degree] = a[k] xor a[k + t1] xor ...``, all-ones initial state.

    Parameters
    ----------
    degree : int
        Degree of the feedback polynomial.
    taps : tuple of int
        Exponents of its middle terms (below ``degree``).

    Returns
    -------
    ndarray of int8, shape (2^degree - 1,)
        One period of the sequence (0/1).
    """
    n = 2**degree - 1
    a = np.zeros(n + degree, np.int8)
    a[:degree] = 1
    for k in range(n):          # code construction (once per code family)
        v = a[k]
        for t in taps:
            v ^= a[k + t]
        a[k + degree] = v
    return a[:n]


def gold_codes(degree: int = 7) -> np.ndarray:
    """The Gold family of length ``N = 2^degree - 1`` as +-1 chips, shape (N + 2, N).

    Codes ``u``, ``v`` and ``u xor shift(v, k)``, ``k = 0..N-1``, from a preferred pair: the
    periodic cross-correlations take only the values ``-1``, ``-t(n)`` and ``t(n) - 2`` with
    ``t(n) = 1 + 2^((n + 2) // 2)`` (Gold, 1967).

    Parameters
    ----------
    degree : int
        Degree of the preferred pair (one of ``PREFERRED_PAIRS``).

    Returns
    -------
    ndarray, shape (N + 2, N)
        The codes as +-1 chips.

    Raises
    ------
    ConfigError
        No preferred pair of that degree.
    """
    if degree not in PREFERRED_PAIRS:
        raise ConfigError(f"code_degree: Gold codes available for {sorted(PREFERRED_PAIRS)}, got {degree}")
    tu, tv = PREFERRED_PAIRS[degree]
    u = m_sequence(degree, tu)
    v = m_sequence(degree, tv)
    n = u.size
    shifts = (np.arange(n)[:, None] + np.arange(n)[None, :]) % n
    fam = np.concatenate([u[None], v[None], u[None] ^ v[shifts]], axis=0)
    return 1.0 - 2.0 * fam


@dataclass(frozen=True)
class CDMAConfig:
    """Physical-layer settings of the RTS/ACK hand-shake.

    chip_s: chip period (paper: 100 ns).
    samples_per_chip: receiver samples per chip (the fractional-chip delay grid).
    code_degree: Gold code degree n (length 2^n - 1; processing gain 2^n - 1).
    tx_power_w: transmit power of every ACK [W].
    noise_figure_db, temperature_k: receiver noise density N0 = k T F; per complex sample
        the noise variance is N0 x sample rate.
    turnaround_s: known delay between RTS reception and ACK transmission.
    turnaround_jitter_s: standard deviation of the responder's clock error over the
        turnaround, Gaussian (its RTS synchronisation error comes from ``rts_sync``).
    rts_sync: how a responder times its ACK: ``"detected"`` (default): it detects the RTS
        (the master's code over the same channel, with receiver noise) with the same OMP-SIC
        detector as the master and answers a turnaround after its estimated first arrival;
        a responder that detects nothing does not answer. ``"ideal"`` (labelled variant):
        it answers a turnaround after the true first path.
    window_s: search window for ACK arrivals after the turnaround (round-trip times).
    random_path_phases: draw every path's phase uniformly in each ACK set (small-scale
        fading); otherwise the ray tracer's phases plus one random phase per ACK.
    """

    chip_s: float = 100e-9
    samples_per_chip: int = 4
    code_degree: int = 7
    tx_power_w: float = 1.0
    noise_figure_db: float = 7.0
    temperature_k: float = 290.0
    turnaround_s: float = 10e-6
    turnaround_jitter_s: float = 5e-9
    window_s: float = 16e-6
    random_path_phases: bool = True
    rts_sync: str = "detected"

    def __post_init__(self):
        if self.rts_sync not in ("detected", "ideal"):
            raise ConfigError(f"rts_sync: expected 'detected' or 'ideal', got {self.rts_sync!r}")
        check_positive(self.chip_s, "chip_s")
        if int(self.samples_per_chip) != self.samples_per_chip or self.samples_per_chip < 1:
            raise ConfigError(f"samples_per_chip: expected a positive integer, got {self.samples_per_chip}")
        check_positive(self.tx_power_w, "tx_power_w")
        check_positive(self.temperature_k, "temperature_k")
        check_positive(self.turnaround_s, "turnaround_s")
        check_positive(self.turnaround_jitter_s, "turnaround_jitter_s", allow_zero=True)
        check_positive(self.window_s, "window_s")

    @property
    def sample_s(self) -> float:
        """Sample period [s]: the chip period over the samples per chip."""
        return self.chip_s / self.samples_per_chip

    @property
    def noise_var(self) -> float:
        """Noise variance per complex sample [W]."""
        return K_BOLTZMANN * self.temperature_k * 10 ** (self.noise_figure_db / 10) / self.sample_s

    @property
    def n_delays(self) -> int:
        """Number of fractional-chip delay cells in the search window."""
        return int(round(self.window_s / self.sample_s))

    @property
    def code_samples(self) -> int:
        """Samples per code period."""
        return (2**self.code_degree - 1) * self.samples_per_chip

    @property
    def n_samples(self) -> int:
        """Length of the received window: every delay cell holds a whole code."""
        return self.n_delays + self.code_samples - 1


def upsample(codes: np.ndarray, samples_per_chip: int) -> np.ndarray:
    """Rectangular chips sampled ``samples_per_chip`` times.

    Parameters
    ----------
    codes : ndarray, shape (..., N)
        Chips.
    samples_per_chip : int

    Returns
    -------
    ndarray, shape (..., N * samples_per_chip)
    """
    return np.repeat(codes, samples_per_chip, axis=-1)


def _synthesize(out, delays, gains, code_idx, codes, sample_s, chip_s):
    """Add every path's delayed, chip-sampled code to ``out`` (B, N), in place.

    Path ``p`` of user ``u`` in set ``b`` adds ``g c(m)`` at every sample ``n`` whose chip
    index ``m = floor((n T_s - tau) / T_c)`` lies in the code (a 1e-9 guard keeps a delay on
    a sample boundary on that sample). Vectorised over sets and samples.
    """
    B, U, P = delays.shape
    L = codes.shape[1]
    n = np.arange(out.shape[1])
    for u in range(U):
        c = codes[code_idx[:, u]]                                          # (B, L)
        for p in range(P):
            tau = delays[:, u, p, None]
            m = np.floor((n * sample_s - tau) / chip_s + 1e-9).astype(np.int64)   # (B, N)
            live = (m >= 0) & (m < L) & (n >= np.ceil(tau / sample_s - 1e-9)) \
                & (gains[:, u, p, None] != 0)
            chip = np.take_along_axis(c, np.clip(m, 0, L - 1), axis=1)
            out += np.where(live, gains[:, u, p, None] * chip, 0)


def received_acks(delays: np.ndarray, gains: np.ndarray, code_idx: np.ndarray,
                  config: CDMAConfig, rng: np.random.Generator,
                  codes: np.ndarray | None = None, backend: str = "numba") -> np.ndarray:
    """The master's baseband over the search window, for a batch of ACK sets.

    ``y_b[n] = sum_u sum_p g_bup c_u(floor((n T_s - tau_bup) / T_c)) + noise``: every path
    of every responder adds its code, delayed and sampled ``samples_per_chip`` times a chip.

    Parameters
    ----------
    delays : ndarray (B, U, P)
        Arrival times of every path of every responder, relative to the start of the
        window (the RTS time plus the turnaround) [s]; NaN for absent paths.
    gains : ndarray (B, U, P), complex
        Amplitude gains of the paths (channel only; the transmit power is applied here).
    code_idx : ndarray (B, U), int
        Gold code of each responder.
    config : CDMAConfig
    rng : numpy Generator
        Noise (and nothing else).
    codes : ndarray, optional
        Code table (+-1 chips); default :func:`gold_codes` of ``config.code_degree``.
    backend : {"numba", "numpy"}
        The compiled sum (default) or its NumPy definition.

    Returns
    -------
    ndarray (B, config.n_samples), complex
    """
    check_backend(backend)
    codes = gold_codes(config.code_degree) if codes is None else codes
    delays = np.asarray(delays, float)
    gains = np.asarray(gains, complex)
    code_idx = np.asarray(code_idx, np.int64)
    if delays.shape != gains.shape or delays.ndim != 3:
        raise InputError(f"delays, gains: expected equal (B, U, P) shapes, got {delays.shape}, {gains.shape}")
    if code_idx.shape != delays.shape[:2]:
        raise InputError(f"code_idx: expected shape {delays.shape[:2]}, got {code_idx.shape}")
    if np.any((code_idx < 0) | (code_idx >= len(codes))):
        raise InputError(f"code_idx: values must lie in 0..{len(codes) - 1}")
    absent = ~np.isfinite(delays)
    if np.any(delays[~absent] < 0):
        raise InputError("delays: an arrival precedes the search window")
    g = np.where(absent, 0.0, gains) * np.sqrt(config.tx_power_w)
    d = np.where(absent, 0.0, delays)
    B = delays.shape[0]
    y = np.zeros((B, config.n_samples), complex)
    synthesize = compiled._synthesize if backend == "numba" else _synthesize
    synthesize(y, d, g, code_idx, codes, config.sample_s, config.chip_s)
    s = np.sqrt(config.noise_var / 2)
    y += s * (rng.standard_normal(y.shape) + 1j * rng.standard_normal(y.shape))
    return y
