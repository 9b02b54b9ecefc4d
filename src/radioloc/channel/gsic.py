"""Multi-user time-of-arrival estimation: an OMP-based successive interference canceller
(OMP-SIC, in the spirit of the paper's GSIC [1]) and the single-user matched filter.

What it is: the paper ranges with GSIC, the generalized successive interference canceller
of its reference [1] (Iltis and Kim), whose equations the paper does not give. This module
implements a successive interference canceller of its own design in that spirit: per-user
tap detection by orthogonal matching pursuit (OMP) inside Gauss-Seidel cancellation sweeps,
with a joint least-squares refit of all users' taps. It is not a transcription of [1]; names
say so (:func:`omp_sic_toa`, :class:`OMPSICConfig`; ``gsic_toa`` and ``GSICConfig`` remain
as aliases).

Signal model (see :mod:`radioloc.channel.cdma`): ``y = sum_u sum_d h_u[d] s_u(. - d) + w``
with ``s_u`` the sampled code of user ``u`` and ``d`` a delay cell on the fractional-chip
grid (``samples_per_chip`` cells per chip).

Per-user tap estimation (:func:`estimate_taps`): the normalised correlator output
``z_u[d] = <s_u(. - d), r> / ||s_u||^2`` of a residual ``r`` is searched by orthogonal
matching pursuit: the strongest cell of the current residual above the detection threshold
joins the support, all amplitudes on the support are refitted by least squares with the
Gram matrix ``R_u[k_i - k_j]`` (``R_u`` the normalised autocorrelation), their contribution
is removed from the correlator output, and the search repeats up to ``max_taps`` times.
This cleans the user's own multipath sidelobes, so the earliest tap is a path and not a
sidelobe.

Detection threshold: the noise floor of the correlator output is estimated as
``median_d |z_u[d]|^2 / ln 2`` (the median of an exponential variable; robust to the few
path cells), re-estimated after each detected tap is removed so that the sidelobes of a
strong path do not hide a weak earlier one. For white noise of variance ``sigma^2`` per sample this floor equals
``sigma^2 / (G Ns)`` with ``G`` the processing gain (chips per code) and ``Ns`` the samples
per chip. A cell is a path when ``|z|^2 > eta^2 floor`` with ``eta^2 = ln(D / p_fa)``
(false-alarm probability ``p_fa`` over the ``D`` cells of the window).

OMP-SIC (:func:`omp_sic_toa`): in each sweep the users are taken one at a time, always the
remaining user whose correlator peak (on ``y`` minus the other users' current
reconstructions) is the strongest; its taps are re-estimated on that residual and its
reconstruction is updated before the next user; the sweep is repeated ``iterations`` times
(Gauss-Seidel). The first arrival of a user is its
earliest detected tap (not its strongest). The matched-filter baseline
(:func:`matched_filter_toa`) runs the same per-user detection on ``y`` itself, without
cancelling the other users.

A detected cell ``d`` covers true delays in ``((d - 1) Ts, d Ts]`` (the chip pulse is
sampled), so the reported arrival is the cell centre ``(d - 1/2) Ts``.

Implementation: the correlator outputs of ``y`` are computed once by FFT; everything after
that is linear in them, so the cancellation works in the correlation domain: removing a
tap ``a`` of user ``v`` at cell ``k`` from user ``u``'s correlator output subtracts
``a X_uv[d - k] / E_u`` (``X_uv`` the codes' aperiodic cross-correlation, ``E_u`` the code
energy), and the joint refit's residual power is ``||y||^2 - 2 Re(a^H r) + a^H G a``. The
sweeps run in a compiled kernel (numba), in parallel over ACK sets. ``backend="numpy"``
runs the plain NumPy implementation that reconstructs and subtracts in the time domain
(the reference the compiled kernel is tested against: same detections, amplitudes equal
to rounding).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft as sp_fft


from radioloc.channel import compiled
from radioloc.channel.cdma import CDMAConfig, upsample
from radioloc.core.backend import check_backend
from radioloc.core.errors import ConfigError, InputError
from radioloc.core.links import pack_mask
from radioloc.core.validation import check_probability


@dataclass(frozen=True)
class OMPSICConfig:
    """Settings of the OMP-based successive interference canceller.

    iterations: sweeps of successive cancellation over all users.
    max_taps: taps detected per user and pass.
    false_alarm: probability of a noise-only cell crossing the threshold anywhere in the
        window (sets eta).
    first_sweep_taps: taps per user in the first sweep (1: classic SIC of each user's
        strongest path), so that cross-correlation spurs of users not yet cancelled are not
        reconstructed and then subtracted from everyone else.
    joint_refit: after every sweep, refit all users' detected taps jointly by least squares
        (with the codes' cross-correlations) and drop taps whose amplitude does not clear
        the noise threshold, with the noise variance estimated from the final residual.
    early_relative: in every sweep but the last, taps weaker than this fraction of the
        user's strongest correlator cell (power) are not detected (0: off); the last sweep
        uses the noise threshold alone.
    """

    iterations: int = 4
    max_taps: int = 8
    false_alarm: float = 1e-2
    early_relative: float = 0.0
    first_sweep_taps: int = 1
    joint_refit: bool = True

    def __post_init__(self):
        if self.iterations < 1 or self.max_taps < 1:
            raise ConfigError("iterations, max_taps: must be >= 1")
        if self.first_sweep_taps < 1:
            raise ConfigError(f"first_sweep_taps: must be >= 1, got {self.first_sweep_taps}")
        check_probability(self.false_alarm, "false_alarm")
        check_probability(self.early_relative, "early_relative")


#: Former name of :class:`OMPSICConfig` (the estimator is an OMP-based SIC, not [1]'s GSIC).
GSICConfig = OMPSICConfig


@dataclass(frozen=True)
class ToAResult:
    """First arrivals of a batch of ACK sets.

    toa_s: (B, U) first-arrival time after the window start [s]; NaN when no tap is detected.
    taps: (B, U, D) estimated complex taps on the delay grid.
    detected: (B, U) whether any tap crossed the threshold.
    """

    toa_s: np.ndarray
    taps: np.ndarray
    detected: np.ndarray


class _Codes:
    """FFT-domain code replicas of the users of each ACK set."""

    def __init__(self, code_idx: np.ndarray, codes: np.ndarray, cdma: CDMAConfig, n_samples: int):
        s = upsample(codes[code_idx], cdma.samples_per_chip)              # (B, U, Ls)
        self.Ls = s.shape[-1]
        self.D = n_samples - self.Ls + 1
        self.nfft = int(2 ** np.ceil(np.log2(n_samples + self.Ls)))
        self.energy = np.sum(s**2, axis=-1)                               # (B, U)
        self.S = np.fft.fft(s, self.nfft, axis=-1)
        ac = np.fft.ifft(self.S * np.conj(self.S), axis=-1).real          # circular, zero-padded
        lags = np.arange(-(self.D - 1), self.D)
        self.R = ac[..., lags % self.nfft] / self.energy[..., None]       # (B, U, 2D-1)

    def correlate(self, r: np.ndarray, users=slice(None)) -> np.ndarray:
        """z[b, u, d] = <s_u(. - d), r_b> / E_u for d = 0..D-1."""
        Rf = np.fft.fft(r, self.nfft, axis=-1)
        if Rf.ndim == 2:
            Rf = Rf[:, None]
        z = np.fft.ifft(Rf * np.conj(self.S[:, users]), axis=-1)[..., : self.D]
        return z / self.energy[:, users, None]


def estimate_taps(z: np.ndarray, R: np.ndarray, max_taps: int, eta2: float,
                  relative: float = 0.0, floor: np.ndarray | None = None) -> np.ndarray:
    """Tap detection on correlator outputs by orthogonal matching pursuit (module docstring).

    Parameters
    ----------
    z : ndarray (..., D) complex
        Normalised correlator outputs.
    R : ndarray (..., 2D - 1)
        Normalised autocorrelation of each user's code at lags -(D-1)..D-1.
    max_taps : int
    eta2 : float
        Threshold factor on the noise floor.
    relative : float
        Taps weaker (in power) than ``relative`` times the strongest cell are not detected.
    floor : ndarray (...), optional
        Known noise floor of ``z`` (noise variance / code energy); default: estimated as
        the median of ``|z|^2`` / ln 2 after each detected tap is removed.

    Returns
    -------
    ndarray (..., D) complex taps (zero where nothing was detected).
    """
    D = z.shape[-1]
    lead = z.shape[:-1]
    z0 = z.reshape(-1, D)
    flat_R = R.reshape(-1, R.shape[-1])
    n = z0.shape[0]
    rows = np.arange(n)
    grid = np.arange(D)
    resid = z0.copy()
    support = np.zeros((n, max_taps), np.int64)
    active = np.zeros((n, max_taps), bool)
    amp = np.zeros((n, max_taps), complex)
    strongest = relative * np.max(np.abs(z0) ** 2, axis=-1)
    for t in range(max_taps):                     # orthogonal matching pursuit, vectorised
        p = np.abs(resid) ** 2
        fl = np.median(p, axis=-1) / np.log(2.0) if floor is None else floor   # noise floor
        thr = np.maximum(eta2 * fl, strongest)
        k = np.argmax(p, axis=-1)
        hit = p[rows, k] > thr
        if t:
            hit &= active[:, t - 1]                  # a stopped search stays stopped
        if not hit.any():
            break
        support[:, t] = k
        active[:, t] = hit
        # least squares on the support: G a = z0[support], G_ij = R[k_i - k_j]
        kk = support[:, : t + 1]
        on = active[:, : t + 1]
        G = flat_R[rows[:, None, None], kk[:, :, None] - kk[:, None, :] + D - 1]
        both = on[:, :, None] & on[:, None, :]
        G = np.where(both, G, 0.0) + np.eye(t + 1) * np.where(on, 1e-9, 1.0)[:, :, None]
        rhs = np.where(on, z0[rows[:, None], kk], 0.0)
        amp[:, : t + 1] = np.linalg.solve(G.astype(complex), rhs[..., None])[..., 0]
        amp[:, : t + 1] *= on
        contrib = flat_R[rows[:, None, None], grid[None, None, :] - kk[:, :, None] + D - 1]
        resid = z0 - np.einsum("nt,ntd->nd", amp[:, : t + 1], contrib)
    taps = np.zeros((n, D), complex)
    np.add.at(taps, (np.repeat(rows, max_taps), support.reshape(-1)), (amp * active).reshape(-1))
    return taps.reshape(lead + (D,))


def _first_arrival(taps: np.ndarray, sample_s: float) -> tuple[np.ndarray, np.ndarray]:
    nz = taps != 0
    detected = nz.any(axis=-1)
    first = np.argmax(nz, axis=-1)
    toa = np.where(detected, (first - 0.5) * sample_s, np.nan)
    return toa, detected


def _check(y, code_idx, cdma):
    y = np.asarray(y)
    if y.ndim != 2 or y.shape[1] != cdma.n_samples:
        raise InputError(f"y: expected shape (B, {cdma.n_samples}), got {y.shape}")
    if not np.all(np.isfinite(y)):
        raise InputError("y: non-finite samples")
    code_idx = np.asarray(code_idx)
    if code_idx.ndim != 2 or code_idx.shape[0] != y.shape[0]:
        raise InputError(f"code_idx: expected shape ({y.shape[0]}, U), got {code_idx.shape}")
    return y, code_idx


def _eta2(cfg: GSICConfig, D: int) -> float:
    return float(np.log(D / cfg.false_alarm))


class _CodeTables:
    """Correlation tables of the distinct codes of a batch (for the compiled kernels).

    ``cidx`` (B, U) maps each user of each ACK set to a distinct code; ``E`` (C,) the code
    energies; ``X`` (C, C, 2D - 1) the aperiodic cross-correlations
    ``X_uv[m] = sum_n s_u[n] s_v[n + m]`` at lags ``m = -(D-1)..D-1``; ``z`` (B, U, D) the
    normalised correlator outputs of ``y``."""

    def __init__(self, y: np.ndarray, code_idx: np.ndarray, codes: np.ndarray, cdma: CDMAConfig):
        uniq, inv = np.unique(code_idx, return_inverse=True)
        self.cidx = inv.reshape(code_idx.shape).astype(np.int64)
        s = upsample(codes[uniq], cdma.samples_per_chip)                   # (C, Ls)
        N = y.shape[1]
        Ls = s.shape[-1]
        self.D = D = N - Ls + 1
        nfft = int(2 ** np.ceil(np.log2(N + Ls)))
        self.E = np.sum(s**2, axis=-1)
        S = sp_fft.fft(s, nfft, axis=-1)
        lags = np.arange(-(D - 1), D) % nfft
        self.X = np.ascontiguousarray(
            sp_fft.ifft(np.conj(S)[:, None, :] * S[None, :, :], axis=-1).real[..., lags])
        self.Xn = self.X / self.E[:, None, None]                          # row-normalised
        Y = sp_fft.fft(y, nfft, axis=-1)
        z = sp_fft.ifft(Y[:, None, :] * np.conj(S)[self.cidx], axis=-1)[..., :D]
        self.z = np.ascontiguousarray(z / self.E[self.cidx][..., None])
        self.y_energy = np.sum(np.abs(y) ** 2, axis=-1)
        self.N = N


def matched_filter_toa(y: np.ndarray, code_idx: np.ndarray, codes: np.ndarray,
                       cdma: CDMAConfig, config: OMPSICConfig | None = None,
                       backend: str = "numba") -> ToAResult:
    """Single-user baseline: correlate ``y`` with each user's code, no cancellation.

    Each user's taps are detected by the same orthogonal matching pursuit as in
    :func:`omp_sic_toa`, on the correlator output of ``y`` itself.

    Parameters
    ----------
    y : ndarray (B, N) complex
        Received windows (:func:`radioloc.channel.cdma.received_acks`).
    code_idx : ndarray (B, U) int
        Code of each user of each window.
    codes : ndarray
        The code table (+-1 chips).
    cdma : CDMAConfig
    config : OMPSICConfig, optional
        ``max_taps`` and ``false_alarm`` are used.
    backend : {"numba", "numpy"}
        The compiled kernel (default) or the plain NumPy reference.

    Returns
    -------
    ToAResult
        First-arrival times (NaN where nothing was detected), taps and detections.
    """
    cfg = config or OMPSICConfig()
    y, code_idx = _check(y, code_idx, cdma)
    if check_backend(backend) == "numpy":
        C = _Codes(code_idx, codes, cdma, y.shape[1])
        taps = estimate_taps(C.correlate(y), C.R, cfg.max_taps, _eta2(cfg, C.D))
    else:
        T = _CodeTables(y, code_idx, codes, cdma)
        taps = compiled._omp_batch(T.z, T.Xn, T.cidx, cfg.max_taps, _eta2(cfg, T.D))
    toa, det = _first_arrival(taps, cdma.sample_s)
    return ToAResult(toa, taps, det)


def omp_sic_toa(y: np.ndarray, code_idx: np.ndarray, codes: np.ndarray, cdma: CDMAConfig,
                config: OMPSICConfig | None = None, noise_var: float | None = None,
                backend: str = "numba") -> ToAResult:
    """Multi-user first arrivals by OMP-based successive interference cancellation.

    The estimator of the module docstring (in the spirit of the paper's GSIC [1], not a
    transcription of it).

    Parameters
    ----------
    y : ndarray (B, N) complex
        Received windows (:func:`radioloc.channel.cdma.received_acks`).
    code_idx : ndarray (B, U) int
        Code of each user of each window.
    codes : ndarray
        The code table (+-1 chips).
    cdma : CDMAConfig
    config : OMPSICConfig, optional
        Cancellation settings.
    noise_var : float, optional
        Noise variance per sample; default: estimated from the data (the median noise
        floor during the sweeps, the final residual in the joint refit).
    backend : {"numba", "numpy"}
        The compiled correlation-domain kernel (default) or the plain NumPy reference.

    Returns
    -------
    ToAResult
        First-arrival times (NaN where nothing was detected), taps and detections.
    """
    cfg = config or OMPSICConfig()
    y, code_idx = _check(y, code_idx, cdma)
    if check_backend(backend) == "numpy":
        return _omp_sic_numpy(y, code_idx, codes, cdma, cfg, noise_var)
    T = _CodeTables(y, code_idx, codes, cdma)
    taps = compiled._sic_batch(T.z, T.X, T.Xn, T.E, T.cidx, T.y_energy, T.N, cfg.iterations, cfg.max_taps,
                      cfg.first_sweep_taps, cfg.early_relative, bool(cfg.joint_refit),
                      _eta2(cfg, T.D), -1.0 if noise_var is None else float(noise_var))
    toa, det = _first_arrival(taps, cdma.sample_s)
    return ToAResult(toa, taps, det)


#: Former name of :func:`omp_sic_toa`.
gsic_toa = omp_sic_toa


def _omp_sic_numpy(y, code_idx, codes, cdma, cfg, noise_var):
    """The plain NumPy implementation (time-domain reconstruction and subtraction)."""
    B, U = code_idx.shape
    C = _Codes(code_idx, codes, cdma, y.shape[1])
    eta2 = _eta2(cfg, C.D)
    rows = np.arange(B)
    xc = _cross_table(C) if cfg.joint_refit else None
    taps = np.zeros((B, U, C.D), complex)
    total = np.zeros_like(y)                          # sum of every user's reconstruction
    for sweep in range(cfg.iterations):               # cancellation sweeps
        rel = 0.0 if sweep == cfg.iterations - 1 else cfg.early_relative
        ntaps = cfg.first_sweep_taps if sweep == 0 and cfg.iterations > 1 else cfg.max_taps
        done = np.zeros((B, U), bool)
        for _stage in range(U):                       # successive: one user at a time
            # z_u of y minus the *other* users = z_u(y - total) + z_u(own reconstruction)
            own = np.fft.ifft(np.fft.fft(taps, C.nfft, axis=-1) * np.abs(C.S) ** 2,
                              axis=-1)[..., : C.D] / C.energy[..., None]
            z_all = C.correlate(y - total) + own
            peak = np.where(done, -1.0, np.max(np.abs(z_all) ** 2, axis=-1))
            u = np.argmax(peak, axis=-1)                                  # strongest remaining
            done[rows, u] = True
            floor = None if noise_var is None else noise_var / C.energy[rows, u]
            t = estimate_taps(z_all[rows, u], C.R[rows, u], ntaps, eta2, rel, floor)
            old = np.fft.ifft(np.fft.fft(taps[rows, u], C.nfft, axis=-1) * C.S[rows, u],
                              axis=-1)[:, : y.shape[1]]
            new = np.fft.ifft(np.fft.fft(t, C.nfft, axis=-1) * C.S[rows, u], axis=-1)[:, : y.shape[1]]
            total += new - old
            taps[rows, u] = t
        if cfg.joint_refit:
            taps = _joint_refit(C, xc, y, taps, cfg.max_taps, eta2, noise_var)
            H = np.fft.fft(taps, C.nfft, axis=-1)
            total = np.fft.ifft(H * C.S, axis=-1)[..., : y.shape[1]].sum(axis=1)
    toa, det = _first_arrival(taps, cdma.sample_s)
    return ToAResult(toa, taps, det)


# ---------------------------------------------------------------- compiled kernels


def _cross_table(C: _Codes) -> np.ndarray:
    """c_uv[m] = sum_n s_u[n] s_v[n + m] for every pair of users, index m mod nfft."""
    return np.fft.ifft(np.conj(C.S)[:, :, None] * C.S[:, None, :], axis=-1).real


def _joint_refit(C: _Codes, xc: np.ndarray, y: np.ndarray, taps: np.ndarray, T: int,
                 eta2: float, noise_var: float | None) -> np.ndarray:
    """Joint least squares of every user's detected taps, then pruning of the taps whose
    amplitude does not clear the noise threshold, and a second solve on what is left.

    A tap that one user picked up from another user's cross-correlation spur gets a small
    amplitude once the true tap of the other user is in the joint model, and is pruned."""
    B, U, D = taps.shape
    rows = np.arange(B)[:, None]
    z_y = C.correlate(y)                                                # (B, U, D)
    for _ in range(2):
        on = taps != 0
        k = pack_mask(on, T)[0]                                          # (B, U, T)
        valid = np.take_along_axis(on, k, axis=-1).reshape(B, U * T)
        kk = k.reshape(B, U * T)
        uu = np.repeat(np.arange(U), T)[None, :].repeat(B, axis=0)
        lag = (kk[:, :, None] - kk[:, None, :]) % C.nfft
        G = xc[rows[:, :, None], uu[:, :, None], uu[:, None, :], lag]     # (B, UT, UT)
        both = valid[:, :, None] & valid[:, None, :]
        n = U * T
        G = np.where(both, G, 0.0) + np.eye(n) * np.where(valid, 1e-9, 1.0)[:, :, None]
        rhs = np.where(valid, (z_y * C.energy[..., None])[rows, uu, kk], 0.0)
        a = np.linalg.solve(G.astype(complex), rhs[..., None])[..., 0]
        new = np.zeros_like(taps)
        new[rows, uu, kk] = np.where(valid, a, 0.0)
        H = np.fft.fft(new, C.nfft, axis=-1)
        resid = y - np.fft.ifft(H * C.S, axis=-1)[..., : y.shape[1]].sum(axis=1)
        nv = np.mean(np.abs(resid) ** 2, axis=-1) if noise_var is None else np.full(B, noise_var)
        floor = nv[:, None, None] / C.energy[..., None]
        taps = np.where(np.abs(new) ** 2 > eta2 * floor, new, 0.0)
    return taps
