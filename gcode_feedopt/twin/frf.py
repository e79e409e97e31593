"""Known uncertainty: a set of measured FRFs -> Gaussian FRF coefficients -> Gaussian impulse
response (paper Eqs. 9–12, done right for a real impulse response; see docs/twin.md).

The N_H FRFs of an axis give, at every frequency bin k, samples of the real part a_k and the
imaginary part b_k. Each is modelled as an independent Gaussian (paper Eq. 9: 3σ = half the
min–max range; or the sample variance). The impulse response is real, so its spectrum is
Hermitian and only the one-sided bins k = 0 … N/2 are free:

    h[n] = (1/N) [ a_0 + (−1)^n a_{N/2} + 2 Σ_{k=1}^{N/2−1} (a_k cos(2πkn/N) − b_k sin(2πkn/N)) ]

h is linear in (a, b): h = A a + B b, so h ~ N(A μ_a + B μ_b, A D_a Aᵀ + B D_b Bᵀ). The paper's
Eq. 11 sums (σ_a² − σ_b²) e^{…} over both signs of k; that is neither the variance of a real
h (it can be negative) nor does it carry the factor 2 of the paired bins or the covariance
between taps. We keep the covariance as a low-rank factor ``L`` (n_taps × r, Σ_h = L Lᵀ): the
variance of the predicted position needs it (a machine standing still after a long move has a
certain position because the DC gain is certain; the diagonal-only formula says otherwise).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Bins whose coefficient spread is below this fraction of the largest are dropped from the
#: low-rank covariance factor (they change no variance by more than 1e-12 relative).
RANK_DROP = 1e-9


@dataclass(frozen=True)
class CoefficientStats:
    """Gaussian FRF coefficients on the DFT bins k = 0 … N/2.

    Attributes:
        n_dft: N, the DFT length = 1/(Ts·Δf).
        mu: (N/2+1,) complex mean μ_a + j μ_b.
        sigma_re, sigma_im: (N/2+1,) standard deviations of a_k and b_k.
    """

    n_dft: int
    mu: np.ndarray
    sigma_re: np.ndarray
    sigma_im: np.ndarray


@dataclass(frozen=True)
class ImpulseResponse:
    """Gaussian impulse response of one axis, taps n = 0 … n_taps−1 at Ts.

    Attributes:
        ts_s: sample period.
        mean: (n,) tap means.
        var: (n,) tap variances.
        factor: (n, r) low-rank factor L with Σ_h = L Lᵀ.
    """

    ts_s: float
    mean: np.ndarray
    var: np.ndarray
    factor: np.ndarray

    @property
    def cov(self) -> np.ndarray:
        """(n, n) tap covariance Σ_h = L Lᵀ."""
        return self.factor @ self.factor.T

    @property
    def n_taps(self) -> int:
        return int(self.mean.size)


def dft_grid(freq_hz: np.ndarray, ts_s: float) -> tuple[int, np.ndarray]:
    """N and the one-sided DFT bin frequencies implied by the FRF grid's spacing and Ts."""
    df = float(np.median(np.diff(freq_hz)))
    n = int(round(1.0 / (ts_s * df)))
    n += n % 2
    return n, np.arange(n // 2 + 1) / (n * ts_s)


def _on_bins(freq_hz: np.ndarray, response: np.ndarray, bins_hz: np.ndarray) -> np.ndarray:
    """Responses (N_H, K) interpolated to the DFT bins (linear in real and imaginary parts);
    beyond the measured band the response is taken as zero (a servo rolls off)."""
    r = np.atleast_2d(response)
    if r.shape[1] == bins_hz.size and np.allclose(freq_hz, bins_hz, rtol=0, atol=1e-9 * bins_hz[-1]):
        return r.astype(complex)
    out = np.empty((r.shape[0], bins_hz.size), complex)
    for i in range(r.shape[0]):
        re = np.interp(bins_hz, freq_hz, r[i].real, left=r[i, 0].real, right=0.0)
        im = np.interp(bins_hz, freq_hz, r[i].imag, left=0.0, right=0.0)
        out[i] = re + 1j * im
    return out


def coefficient_stats(freq_hz: np.ndarray, response: np.ndarray, ts_s: float,
                      method: str = "minmax") -> CoefficientStats:
    """Gaussian coefficients per DFT bin from N_H FRFs (paper Eq. 9).

    Args:
        freq_hz: (K,) grid of the FRFs.
        response: (N_H, K) complex FRFs.
        ts_s: sample period of the impulse response.
        method: ``minmax`` — μ = (max+min)/2, σ = (max−μ)/3 (the paper); ``sample`` — the
            sample mean and standard deviation (ddof 1).
    """
    n, bins = dft_grid(freq_hz, ts_s)
    H = _on_bins(np.asarray(freq_hz, float), response, bins)
    a, b = H.real, H.imag
    if method == "minmax":
        mu_a = 0.5 * (a.max(0) + a.min(0))
        mu_b = 0.5 * (b.max(0) + b.min(0))
        s_a = (a.max(0) - mu_a) / 3.0
        s_b = (b.max(0) - mu_b) / 3.0
    elif method == "sample":
        mu_a, mu_b = a.mean(0), b.mean(0)
        ddof = 1 if a.shape[0] > 1 else 0
        s_a, s_b = a.std(0, ddof=ddof), b.std(0, ddof=ddof)
    else:
        raise ValueError(f"coefficient variance method {method!r}: use 'minmax' or 'sample'")
    # a real impulse response has a real spectrum at DC and at Nyquist
    mu_b = mu_b.copy()
    s_b = s_b.copy()
    mu_b[0] = mu_b[-1] = 0.0
    s_b[0] = s_b[-1] = 0.0
    return CoefficientStats(n_dft=n, mu=mu_a + 1j * mu_b, sigma_re=s_a, sigma_im=s_b)


def _basis(n_dft: int, n_taps: int) -> tuple[np.ndarray, np.ndarray]:
    """A (n_taps, K) and B (n_taps, K): h = A a + B b for the one-sided bins, truncated to
    n_taps with the remainder folded into tap 0.

    A sampled FRF of a continuous servo is not band-limited (a base-excited mode has relative
    degree one), so its inverse DFT rings on both sides of t = 0 and the causal taps alone miss
    about 1 % of the DC gain — 0.5 mm after a 50 mm move — and, worse, make it uncertain.
    Folding every tap beyond the window into tap 0 keeps Σ h = H(0) exactly for every draw
    (the FRFs agree at DC, so a machine at rest is where it was commanded, with certainty), and
    is linear, so h stays Gaussian. The draws (:func:`draw_impulse_responses`) fold the same way."""
    k = np.arange(n_dft // 2 + 1)
    n = np.arange(n_taps)[:, None]
    c = np.full(k.size, 2.0)
    c[0] = 1.0
    c[-1] = 1.0
    ang = 2 * np.pi * n * k[None, :] / n_dft
    A = c * np.cos(ang) / n_dft
    B = -c * np.sin(ang) / n_dft
    # Σ over all N taps of the full basis is δ_k0 for A and 0 for B
    A[0] += (k == 0).astype(float) - A.sum(0)
    B[0] += -B.sum(0)
    return A, B


def impulse_response(*args, method: str = "minmax") -> ImpulseResponse:
    """Mean, variance and covariance factor of the impulse response (see module docstring).

    Call as ``(freq_hz, response, ts_s, n_taps)`` or ``(frf_set, ts_s, n_taps)``."""
    freq_hz, response, ts_s, n_taps = _unpack(args)[:4]
    if method == "ensemble":
        return ensemble_impulse_response(freq_hz, response, ts_s, n_taps)
    st = coefficient_stats(freq_hz, response, ts_s, method)
    _check_length(n_taps, st.n_dft)
    A, B = _basis(st.n_dft, n_taps)
    mean = A @ st.mu.real + B @ st.mu.imag
    keep_a = st.sigma_re > RANK_DROP * max(st.sigma_re.max(), 1e-300)
    keep_b = st.sigma_im > RANK_DROP * max(st.sigma_im.max(), 1e-300)
    L = np.hstack([A[:, keep_a] * st.sigma_re[keep_a], B[:, keep_b] * st.sigma_im[keep_b]])
    var = np.einsum("ij,ij->i", L, L)
    return ImpulseResponse(ts_s=ts_s, mean=mean, var=var, factor=compress_factor(L))


def ensemble_impulse_response(freq_hz, response, ts_s: float, n_taps: int) -> ImpulseResponse:
    """Gaussian impulse response from the N_H measured FRFs *as whole responses*: each FRF's
    own impulse response (inverse DFT on the bins, folded as :func:`_basis`), then their
    sample mean and covariance, Σ_h = L Lᵀ with L = (h_i − h̄)ᵀ/√(N_H − 1) (rank ≤ N_H − 1).

    Why (the paper is loose here): Eq. 9 treats every bin's coefficients as independent, so
    a draw is white scatter over all bins — an impulse response whose tail never decays —
    and the predicted position's variance grows with the energy of the motion (on the
    ender3pro set, σ_x̂ ≈ 0.07 mm during printing moves, most of a 0.1 mm tolerance). The
    measured FRFs differ *coherently* (a mode moves or damps as a whole), which the
    per-bin model cannot represent; the ensemble keeps exactly the directions in which the
    measurements differ, with the sample variance along them, and costs N_H − 1 columns
    instead of ~240 (``coef_variance: ensemble`` in a profile)."""
    n, bins = dft_grid(freq_hz, ts_s)
    _check_length(n_taps, n)
    H = _on_bins(np.asarray(freq_hz, float), np.atleast_2d(response), bins)
    H = H.copy()
    H[:, 0] = H[:, 0].real
    H[:, -1] = H[:, -1].real
    h = _fold(np.fft.irfft(H, n=n, axis=1), n_taps)
    mean = h.mean(axis=0)
    if h.shape[0] > 1:
        L = (h - mean).T / np.sqrt(h.shape[0] - 1)
    else:
        L = np.zeros((n_taps, 0))
    var = np.einsum("ij,ij->i", L, L)
    return ImpulseResponse(ts_s=ts_s, mean=mean, var=var, factor=L)


#: Share of the total tap variance the compressed covariance factor must keep (the FRF
#: scatter is spread over every bin, so Σ_h is not low-rank; 99.9 % keeps ~240 of 500
#: directions and changes no standard deviation by more than 0.05 %).
FACTOR_ENERGY = 1.0 - 1e-3


def compress_factor(L: np.ndarray, other: float = 0.0) -> np.ndarray:
    """An (n, r) factor with the same L Lᵀ up to 1e-3 of the whole trace and the fewest
    columns (SVD): the twin convolves the commands with every column, so r sets its cost.

    ``other``: the trace of a part of the covariance kept beside L, uncompressed (the modal
    members' spread beside their fits' own term, ``twin.modal.ensemble_impulse``); the part
    dropped is then at most 1e-3 of both traces together, and may be all of L."""
    if L.shape[1] == 0:
        return L
    U, S, _ = np.linalg.svd(L, full_matrices=False)
    e = np.cumsum(S * S)
    target = FACTOR_ENERGY * e[-1] - (1.0 - FACTOR_ENERGY) * other
    r = int(np.searchsorted(e, target) + 1) if target > 0 or not other else 0
    return U[:, :r] * S[:r]


def draw_coefficients(st: CoefficientStats, rng: np.random.Generator, size: int) -> np.ndarray:
    """(size, N/2+1) complex spectra drawn from the coefficient Gaussians."""
    a = st.mu.real + st.sigma_re * rng.standard_normal((size, st.mu.size))
    b = st.mu.imag + st.sigma_im * rng.standard_normal((size, st.mu.size))
    return a + 1j * b


def _unpack(args):
    """Accept (FRFSet, ...) as well as (freq_hz, response, ...)."""
    if hasattr(args[0], "freq_hz"):
        return (args[0].freq_hz, args[0].response) + tuple(args[1:])
    return tuple(args)


def draw_impulse_responses(*args, size: int | None = None, method: str = "minmax") -> np.ndarray:
    """(size, n_taps) real impulse responses, one per draw of the FRF coefficients.

    Call as ``(freq_hz, response, ts_s, n_taps, rng[, size])`` or ``(frf_set, ts_s, n_taps,
    rng[, size])``."""
    args = _unpack(args)
    freq_hz, response, ts_s, n_taps, rng = args[:5]
    if len(args) > 5:
        size = args[5]
    size = 1 if size is None else int(size)
    if method == "ensemble":
        ir = ensemble_impulse_response(freq_hz, response, ts_s, n_taps)
        z = rng.standard_normal((size, ir.factor.shape[1]))
        return ir.mean[None, :] + z @ ir.factor.T
    st = coefficient_stats(freq_hz, response, ts_s, method)
    _check_length(n_taps, st.n_dft)
    spec = draw_coefficients(st, rng, size)
    h = np.fft.irfft(spec, n=st.n_dft, axis=1)
    return _fold(h, n_taps)


def member_impulses(freq_hz, response, ts_s, n_taps) -> np.ndarray:
    """(N_H, n_taps) impulse response of each measured FRF (same folding as the Gaussian)."""
    n, bins = dft_grid(freq_hz, ts_s)
    _check_length(n_taps, n)
    H = _on_bins(np.asarray(freq_hz, float), response, bins)
    A, B = _basis(n, n_taps)
    return H.real @ A.T + H.imag @ B.T


def _check_length(n_taps: int, n_dft: int) -> None:
    """The bins determine N = 1/(Ts·Δf) taps; beyond them the inverse DFT repeats itself (a
    2 Hz grid at Ts 2 ms: 250 taps, and a 500-tap response would trail its command by 0.5 s)."""
    if n_taps > n_dft:
        raise ValueError(f"n_taps {n_taps} exceeds the estimable length N_h = {n_dft} "
                         "(1/(Ts·Δf)); use a finer FRF grid or fewer taps")


def _fold(h: np.ndarray, n_taps: int) -> np.ndarray:
    """Truncate to n_taps, adding everything beyond (the slow tail and the wrapped negative-
    time ringing) to tap 0. See :func:`_basis`."""
    out = h[..., :n_taps].copy()
    out[..., 0] += h[..., n_taps:].sum(axis=-1)
    return out


def frf_of(profile, axis: str):
    """(freq_hz, response) of a profile's axis, or a ValueError naming the axis."""
    ax = profile.axes.get(axis)
    if ax is None or ax.frf is None:
        raise ValueError(f"profile {profile.name} has no FRFs for axis {axis}")
    return ax.frf.freq_hz, ax.frf.response


def paper_eq11_variance(st: CoefficientStats, n_taps: int) -> np.ndarray:
    """The paper's Eq. 11 tap variance, kept only to show in tests how it differs:
    Re{(1/N) Σ_{k=0}^{N−1} (σ_a² − σ_b²) e^{2πj n k/N}} over the full (two-sided) spectrum."""
    n = st.n_dft
    sa2 = np.concatenate([st.sigma_re ** 2, st.sigma_re[-2:0:-1] ** 2])
    sb2 = np.concatenate([st.sigma_im ** 2, st.sigma_im[-2:0:-1] ** 2])
    v = np.fft.ifft(sa2 - sb2, n=n).real
    return v[:n_taps]
