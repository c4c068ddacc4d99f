"""Exact skyline scores for every heading at once, by FFT circular correlation.

For a query skyline ``e`` (N samples, relative to the heading; ``w_j = 1`` where seen) and a
database skyline ``s`` (N samples, absolute azimuths), the score of heading shift ``a`` is the
least-squares residual of

    e_j = s_(j+a) + mu + alpha cos(theta_j) + beta sin(theta_j) + noise      (j seen)

where ``theta_j`` is the query sample's azimuth relative to the heading.  ``model="offset"``
keeps only ``mu``: that is the reference report's metric (sum of squared differences after
removing the mean offset over the seen window).  ``model="tilt"`` adds the first harmonic, the
first-order effect of a pitch/roll of the mast (``delta_el = -pitch cos(theta) - roll sin(theta)``),
which makes the score invariant to small tilts.  An optional ridge ``ridge`` penalises
``ridge * (alpha**2 + beta**2)`` (degrees squared): an IMU prior on the tilt.

Expanding the square gives circular correlations of the database skyline with a handful of
fixed query vectors (``w e``, ``w``, ``w cos``, ``w sin``): a few real DFTs per position, computed
row-wise with OpenCV in float64 (CCS packed spectra), never a loop over headings.  A full
panorama takes a faster path: with ``w = 1`` the model removes DFT bins 0 (and 1), so the score is
the energy of the remaining bins of the residual (Parseval), one inverse DFT per position.

Units: degrees for elevations, degrees squared for scores.  Shift ``a`` means query sample ``j``
is compared with database sample ``(j + a) mod N``; the heading is
``db_start + a * step - query_start`` degrees.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import numpy as np

from board.errors import InvalidInputError

log = logging.getLogger(__name__)

MODELS = ("offset", "tilt")


def dft_rows(x: np.ndarray) -> np.ndarray:
    """Row-wise real DFT of ``x`` (P, N) as OpenCV CCS-packed float64 (P, N)."""
    return cv2.dft(np.ascontiguousarray(x, dtype=np.float64), flags=cv2.DFT_ROWS)


def idft_rows(ccs: np.ndarray) -> np.ndarray:
    """Inverse of :func:`dft_rows` (scaled by 1/N): real (P, N) float64."""
    return cv2.idft(ccs, flags=cv2.DFT_ROWS | cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)


def _ccs_views(c: np.ndarray):
    """(re0, re_pairs, im_pairs, re_nyquist or None) views of CCS rows (last axis N)."""
    n = c.shape[-1]
    m = (n - 1) // 2
    re = c[..., 1:2 * m:2]
    im = c[..., 2:2 * m + 1:2]
    nyq = c[..., n - 1] if n % 2 == 0 else None
    return c[..., 0], re, im, nyq


def bin_energy(c: np.ndarray, skip: int) -> np.ndarray:
    """Sum over all N DFT bins except |k| < ``skip`` of |X_k|^2, from CCS rows (Parseval)."""
    n = c.shape[-1]
    _, re, im, nyq = _ccs_views(c)
    m = re.shape[-1]
    lo = max(skip - 1, 0)
    e = 2.0 * (re[..., lo:m] ** 2 + im[..., lo:m] ** 2).sum(axis=-1)
    if nyq is not None and n // 2 >= skip:
        e = e + nyq ** 2
    if skip <= 0:
        e = e + c[..., 0] ** 2
    return e


def bin_magnitudes(c: np.ndarray, skip: int) -> tuple[np.ndarray, np.ndarray]:
    """|X_k| for k = skip..n//2 and their Parseval multiplicities (2, or 1 for Nyquist)."""
    _, re, im, nyq = _ccs_views(c)
    mags = np.sqrt(re[..., skip - 1:] ** 2 + im[..., skip - 1:] ** 2)
    mult = np.full(mags.shape[-1], 2.0)
    if nyq is not None:
        mags = np.concatenate([mags, np.abs(nyq)[..., None]], axis=-1)
        mult = np.append(mult, 1.0)
    return mags, mult


@dataclass(frozen=True)
class QueryModel:
    """A query skyline prepared for scoring (built once per query by :func:`prepare_query`).

    n : number of azimuth samples; seen : (n,) bool; e : (n,) elevations, degrees, centred on
    their mean over the seen samples, 0 where unseen; basis : (K, n) nuisance regressors
    (1, cos theta, sin theta) times the mask; minv : (K, K) inverse of ``basis basis^T + ridge``;
    model : "offset" or "tilt"; full : every sample seen (fast path).
    """

    n: int
    seen: np.ndarray
    e: np.ndarray
    theta_deg: np.ndarray
    basis: np.ndarray
    minv: np.ndarray
    model: str
    ridge: float
    full: bool
    # spectra (CCS, float64) of the fixed query vectors
    spec_we: np.ndarray
    spec_w: np.ndarray
    spec_basis: np.ndarray
    sum_we2: float
    basis_e: np.ndarray
    # whitening: minv = chol @ chol.T; c = chol.T @ b has |c|^2 = b^T minv b
    chol: np.ndarray = None  # type: ignore[assignment]
    spec_white: np.ndarray = None  # type: ignore[assignment]
    white_e: np.ndarray = None  # type: ignore[assignment]
    _tiled: dict = field(default_factory=dict, repr=False, compare=False)
    _tiled32: dict = field(default_factory=dict, repr=False, compare=False)
    _consts: dict = field(default_factory=dict, repr=False, compare=False)

    def constant(self, name: str, make):
        """A per-query constant ``make(self)``, computed once and kept (bounds, magnitudes)."""
        v = self._consts.get(name)
        if v is None:
            v = self._consts[name] = make(self)
        return v

    def tiled(self, rows: int) -> dict:
        """The query spectra repeated on ``rows`` rows (contiguous, for cv2.mulSpectrums); cached."""
        big = max((k for k in self._tiled if k >= rows), default=None)
        if big is None:
            self._tiled.clear()
            big = max(rows, 1)
            rep = lambda v: np.ascontiguousarray(np.broadcast_to(v, (big, self.n)))  # noqa: E731
            self._tiled[big] = {"we": rep(self.spec_we), "w": rep(self.spec_w),
                                "white": [rep(v) for v in self.spec_white]}
        t = self._tiled[big]
        return {"we": t["we"][:rows], "w": t["w"][:rows], "white": [v[:rows] for v in t["white"]]}

    def tiled32(self, rows: int) -> dict:
        """As :meth:`tiled`, in float32 (for :func:`approx_scores_f32`); cached."""
        big = max((k for k in self._tiled32 if k >= rows), default=None)
        if big is None:
            self._tiled32.clear()
            big = max(rows, 1)
            rep = lambda v: np.ascontiguousarray(np.broadcast_to(v, (big, self.n)), dtype=np.float32)  # noqa: E731
            self._tiled32[big] = {"we": rep(self.spec_we), "w": rep(self.spec_w),
                                  "white": [rep(v) for v in self.spec_white]}
        t = self._tiled32[big]
        return {"we": t["we"][:rows], "w": t["w"][:rows], "white": [v[:rows] for v in t["white"]]}

    @property
    def n_seen(self) -> int:
        return int(self.seen.sum())

    @property
    def n_params(self) -> int:
        return self.basis.shape[0]


def prepare_query(elevation_deg: np.ndarray, *, azimuth_start_deg: float = 0.0, model: str = "tilt",
                  ridge: float = 0.0) -> QueryModel:
    """Prepare a query skyline (degrees, NaN = unseen, relative to the heading) for scoring.

    ``model`` is "offset" (the report's metric) or "tilt" (offset + first harmonic);
    ``ridge`` (degrees^2 per degree^2 of harmonic amplitude) penalises the tilt harmonic.
    """
    if model not in MODELS:
        raise InvalidInputError(f"unknown score model {model!r}: use one of {MODELS}")
    el = np.asarray(elevation_deg, dtype=np.float64)
    n = el.size
    seen = np.isfinite(el)
    n_seen = int(seen.sum())
    k = 1 if model == "offset" else 3
    if n_seen < k + 2:
        raise InvalidInputError(f"the query skyline has {n_seen} seen samples: at least {k + 2} are needed "
                                "to fit the offset and tilt; give a skyline with more of the panorama seen")
    w = seen.astype(np.float64)
    e = np.where(seen, el - el[seen].mean(), 0.0)
    theta = azimuth_start_deg + np.arange(n) * 360.0 / n
    t = np.radians(theta)
    basis = np.stack([np.ones(n), np.cos(t), np.sin(t)])[:k] * w
    gram = basis @ basis.T
    reg = np.zeros((k, k))
    if k == 3:
        reg[1, 1] = reg[2, 2] = float(ridge)
    gram = gram + reg
    if np.linalg.cond(gram) > 1e12:
        raise InvalidInputError("the seen part of the query skyline is too short to separate offset and tilt; "
                                "use --model offset (or an IMU --tilt-prior) or give a wider panorama")
    minv = np.linalg.inv(gram)
    minv = (minv + minv.T) / 2.0
    chol = np.linalg.cholesky(minv)
    full = bool(seen.all())
    spec_basis = dft_rows(basis)
    basis_e = basis @ e
    return QueryModel(
        n=n, seen=seen, e=e, theta_deg=theta, basis=basis, minv=minv, model=model, ridge=float(ridge), full=full,
        spec_we=dft_rows((w * e)[None])[0], spec_w=dft_rows(w[None])[0], spec_basis=spec_basis,
        sum_we2=float((w * e * e).sum()), basis_e=basis_e,
        chol=chol, spec_white=chol.T @ spec_basis, white_e=chol.T @ basis_e,
    )


@dataclass
class ScoreBlock:
    """Scores of a block of P database skylines for every shift: ``scores`` (P, N) degrees^2.

    ``b`` (K, P, N) holds the projections needed to recover the fitted nuisance coefficients
    at any (position, shift): ``coef = minv @ b[:, p, a]`` = (mu, alpha, beta).
    """

    scores: np.ndarray
    b: np.ndarray | None


def lower_bound_full(q: QueryModel, sc: np.ndarray) -> np.ndarray:
    """Heading-free lower bound (degrees^2) of the full-panorama score of each row, from magnitudes.

    For every shift, ``|E_k - w^(ka) S_k| >= | |E_k| - |S_k| |`` bin by bin (Parseval), so
    ``score(p, a) >= sum_k (|E_k| - |S_k|)^2 / N`` over the bins the model does not absorb.  The
    search uses :func:`lower_bound_full_f32`; this float64 form is its reference.
    """
    skip = 1 if q.model == "offset" else 2
    me, mult = bin_magnitudes(q.spec_we[None], skip)
    ms, _ = bin_magnitudes(sc, skip)
    return ((ms - me) ** 2 * mult).sum(axis=-1) / q.n


def lower_bound_full_f32(q: QueryModel, s32: np.ndarray) -> np.ndarray:
    """:func:`lower_bound_full` computed in float32 (about 3x faster), minus a bound on its error.

    ``s32`` : (P, N) float32 rows (any offset: bin 0 is not used), centred for a tight bound.  Still a
    lower bound of every heading's exact score of rows ``x`` with ``|s32 - x - const| <= 2 u |s32|``
    element by element (``x`` rounded to float32 and centred in float32, or the reverse), ``u`` the
    float32 rounding unit: with ``m`` the magnitudes of the kept bins,
    ``sqrt(N lb) = ||m_S - m_E||`` (weighted 2-norm over the bins), and the computed magnitudes differ
    from the exact ones by at most the spectrum's error, ``||dS||_2 <= (g + 2 u) sqrt(N) ||s||_2`` (the
    transform, ``g = 40 u (log2 N + 2)`` as in :func:`f32_error_bound`, and the rounding of the rows),
    plus ``g sqrt(N) ||e||_2`` for the query's rounded magnitudes and the squares, roots and sums; the
    root is lowered by that much.
    """
    n = q.n
    skip = 1 if q.model == "offset" else 2

    def query_terms(q):
        me, mult = bin_magnitudes(q.spec_we[None], skip)
        weight = np.zeros(n)  # CCS slots: the real slot of each kept bin carries its multiplicity
        target = np.zeros(n)
        m = (n - 1) // 2
        slots = list(range(2 * skip - 1, 2 * m, 2)) + ([n - 1] if n % 2 == 0 else [])
        weight[slots] = mult
        target[slots] = me[0]
        norm_e = float(np.sqrt((q.e ** 2).sum()))
        return weight.astype(np.float32), target.astype(np.float32), norm_e

    weight, target, norm_e = q.constant(f"lb_full_f32_{skip}", query_terms)
    rows = s32.shape[0]
    sc = cv2.dft(s32, flags=cv2.DFT_ROWS)
    power = cv2.mulSpectrums(sc, sc, cv2.DFT_ROWS, conjB=True)  # |S_k|^2 in the real slots, 0 elsewhere
    d = cv2.subtract(cv2.sqrt(power), np.broadcast_to(target, (rows, n)))
    root = np.sqrt(cv2.multiply(d, d) @ weight, dtype=np.float64)
    ns = np.sqrt(np.einsum("ij,ij->i", s32, s32).astype(np.float64) * 1.01)  # ||s||_2, raised past its rounding
    g = 40.0 * _U32 * (np.log2(n) + 2.0)
    lowered = root * (1.0 - 1e-5) - np.sqrt(n) * ((g + 2.0 * _U32) * ns + g * norm_e)
    return np.maximum(lowered, 0.0) ** 2 / n


def score_block(q: QueryModel, db: np.ndarray, *, want_b: bool = True, sc: np.ndarray | None = None) -> ScoreBlock:
    """Exact scores (degrees^2) of query ``q`` against database skylines ``db`` (P, N) for every shift.

    ``db`` must be finite (fill or drop missing samples first).  A caller that already has the
    CCS spectrum ``sc`` passes it with ``db`` centred row by row (mean 0).
    """
    db = np.asarray(db, dtype=np.float64)
    if db.ndim != 2 or db.shape[1] != q.n:
        raise InvalidInputError(f"database block has shape {db.shape}, expected (P, {q.n})")
    if sc is None:
        s = db - db.mean(axis=1, keepdims=True)  # any per-row offset is absorbed by mu: improves conditioning
        sc = dft_rows(s)
    else:
        s = db  # the caller centred the rows and transformed them
    if q.full:
        return _score_full(q, sc, want_b)
    return _score_partial(q, s, sc, want_b)


def _score_partial(q: QueryModel, s: np.ndarray, sc: np.ndarray, want_b: bool) -> ScoreBlock:
    """Masked query: 2 forward + (1 + K) inverse real DFTs per row, no loop over rows or shifts.

    score(a) = sum w e^2 + [w * s^2](a) - 2 [w e * s](a) - sum_i c_i(a)^2, where ``[v * x](a) =
    sum_j v_j x_(j+a)`` is a circular correlation and ``c = chol^T (b - basis e)`` the whitened
    projections (``|c|^2 = (b - B e)^T minv (b - B e)``).  Spectral products by cv2.mulSpectrums
    (CCS rows), the two correlations of the first term summed before one inverse DFT.
    """
    t = q.tiled(s.shape[0])
    flags = cv2.DFT_ROWS
    acc = cv2.mulSpectrums(dft_rows(cv2.multiply(s, s)), t["w"], flags, conjB=True)
    cv2.scaleAdd(cv2.mulSpectrums(sc, t["we"], flags, conjB=True), -2.0, acc, dst=acc)
    scores = idft_rows(acc)
    k = q.n_params
    c = np.empty((k,) + s.shape) if want_b else None
    for i in range(k):
        # -c_i = idft(...) - white_e_i; only its square enters the score
        ci = idft_rows(cv2.mulSpectrums(sc, t["white"][i], flags, conjB=True))
        if q.white_e[i] != 0.0:
            cv2.subtract(ci, float(q.white_e[i]), dst=ci)
        cv2.subtract(scores, cv2.multiply(ci, ci), dst=scores)
        if c is not None:
            c[i] = ci
    cv2.add(scores, q.sum_we2, dst=scores)
    cv2.max(scores, 0.0, dst=scores)
    b = None
    if want_b:
        b = np.linalg.solve(q.chol.T, -c.reshape(k, -1)).reshape(c.shape)
    return ScoreBlock(scores, b)


#: float32 rounding unit
_U32 = float(np.finfo(np.float32).eps) / 2.0


def approx_scores_f32(q: QueryModel, s32: np.ndarray) -> np.ndarray:
    """Scores (P, N) of a masked query computed as :func:`score_block` does, in float32 (about 2x faster).

    ``s32`` : (P, N) float32 database skylines centred row by row.  The error is bounded by
    :func:`f32_error_bound`: the search uses these scores only as lower bounds for exact pruning.
    """
    t = q.tiled32(s32.shape[0])
    flags = cv2.DFT_ROWS
    sc = cv2.dft(s32, flags=flags)
    acc = cv2.mulSpectrums(cv2.dft(cv2.multiply(s32, s32), flags=flags), t["w"], flags, conjB=True)
    cv2.scaleAdd(cv2.mulSpectrums(sc, t["we"], flags, conjB=True), -2.0, acc, dst=acc)
    inv = cv2.DFT_ROWS | cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE
    scores = cv2.idft(acc, flags=inv)
    for i in range(q.n_params):
        ci = cv2.idft(cv2.mulSpectrums(sc, t["white"][i], flags, conjB=True), flags=inv)
        if q.white_e[i] != 0.0:
            cv2.subtract(ci, float(q.white_e[i]), dst=ci)
        cv2.subtract(scores, cv2.multiply(ci, ci), dst=scores)
    cv2.add(scores, q.sum_we2, dst=scores)
    return scores


def _max_abs_spectrum(c: np.ndarray) -> float:
    """max_k |X_k| of a CCS-packed real spectrum (N,)."""
    x0, re, im, nyq = _ccs_views(c)
    m = max(abs(float(x0)), float(np.sqrt(re ** 2 + im ** 2).max(initial=0.0)))
    return m if nyq is None else max(m, abs(float(nyq)))


def f32_error_bound(q: QueryModel, s: np.ndarray) -> np.ndarray:
    """Bound (degrees^2, (P,)) on |float32 - exact| of :func:`approx_scores_f32` at every shift, per row.

    ``s`` : the centred rows, float64 or their float32 copy.

    A correlation ``y = IDFT(conj(V) DFT(x))`` computed in precision ``u`` has a max-norm error
    ``|dy|_inf <= |dy|_2 <= g max_k |V_k| ||x||_2``, with ``g`` about ``2 x 7 u log2 N`` for the
    forward and inverse transforms (Higham, *Accuracy and Stability of Numerical Algorithms*,
    sec. 24.1) plus a few ``u`` for the rounding of the inputs, the query spectrum and the
    product; we take ``g = 40 u (log2 N + 2)`` (about 3x margin).  Terms: ``[w * s^2]``,
    ``2 [w e * s]`` and ``c_i^2`` (``|c_i| <= ||white_i||_2 ||s||_2 + |white_e_i|``), plus the
    rounding of the final float32 sum.
    """
    # the norms from float32 copies, raised by far more than their float32 rounding (N u < 1e-4)
    s2 = cv2.multiply(s, s) if s.dtype == np.float32 else cv2.multiply(*(2 * [s.astype(np.float32)]))
    ns2 = s2.sum(axis=1).astype(np.float64) * 1.01
    ns = np.sqrt(ns2)
    n4 = np.sqrt(np.einsum("ij,ij->i", s2, s2).astype(np.float64) * 1.01)  # ||s^2||_2
    g = 40.0 * _U32 * (np.log2(q.n) + 2.0)
    k_w, k_we, norm_basis, k_white = q.constant("f32_bound", _f32_bound_constants)
    err = g * (k_w * n4 + 2.0 * k_we * ns)
    mag = q.sum_we2 + q.n_seen * ns2 + 2.0 * np.sqrt(q.sum_we2 * q.n_seen) * ns
    for i in range(q.n_params):
        ci = norm_basis[i] * ns + abs(q.white_e[i])
        ei = g * k_white[i] * ns
        err += 2.0 * ci * ei + ei * ei
        mag += ci * ci
    return err + 8.0 * _U32 * mag


def _f32_bound_constants(q: QueryModel) -> tuple[float, float, list[float], list[float]]:
    """Per-query factors of :func:`f32_error_bound`: max |W_k|, max |(we)_k|, ||whitened basis_i||, max |white_i,k|."""
    w_basis = q.chol.T @ q.basis  # whitened basis rows (time domain)
    return (_max_abs_spectrum(q.spec_w), _max_abs_spectrum(q.spec_we),
            [float(np.sqrt((w_basis[i] ** 2).sum())) for i in range(q.n_params)],
            [_max_abs_spectrum(q.spec_white[i]) for i in range(q.n_params)])


def _score_full(q: QueryModel, sc: np.ndarray, want_b: bool) -> ScoreBlock:
    """Full panorama: residual energy outside the bins absorbed by the model (0, or 0 and +-1).

    With a ridge the tilt model leaves ``leftover |R_1(a)|^2`` of the first-harmonic residual
    ``R_1(a) = E_1 - w^a S_1``; its heading-dependent part ``-2 leftover Re(conj(E_1) S_1 w^a)`` is
    bin 1 of the same inverse DFT (scaled), so no (P, N) complex array is formed.
    """
    n = q.n
    skip = 1 if q.model == "offset" else 2
    ec = q.spec_we[None]
    acc = cv2.mulSpectrums(sc, q.tiled(sc.shape[0])["we"], cv2.DFT_ROWS, conjB=True)
    acc[:, 0] = 0.0
    const = (bin_energy(ec, skip) + bin_energy(sc, skip)) / n
    b = None
    if skip == 2:
        leftover = 2.0 / n - 1.0 / (n / 2.0 + q.ridge)
        e1 = complex(q.spec_we[1], q.spec_we[2])
        s1 = sc[:, 1] + 1j * sc[:, 2]
        const += leftover * (abs(e1) ** 2 + np.abs(s1) ** 2)
        # idft turns bin 1 (and its mirror) X_1 into (2/N) Re(X_1 w^a): scale X_1 = S_1 conj(E_1)
        # so that -2 idft(acc) carries -2 leftover Re(conj(E_1) S_1 w^a)
        acc[:, 1:3] *= leftover * n / 2.0
        if want_b:
            # b_0 = sum r = R_0 = 0 after centring (both sides centred); b_1 + i b_2 = e^(i theta0) conj(R_1)
            r1 = e1 - s1[:, None] * np.exp(2j * np.pi * np.arange(n) / n)[None, :]
            z = np.exp(1j * np.radians(q.theta_deg[0])) * np.conj(r1)
            b = np.stack([np.zeros(r1.shape), z.real, z.imag])
    scores = idft_rows(acc)  # (1/N) sum over bins conj(E_k) S_k w^(ka), bin 1 scaled as above
    scores *= -2.0
    scores += const[:, None]
    if skip == 1 and want_b:
        b = np.zeros((1,) + scores.shape)
    np.maximum(scores, 0.0, out=scores)
    return ScoreBlock(scores, b)


def heading_deg(shift: np.ndarray | int, *, n: int, db_start_deg: float, query_start_deg: float):
    """Heading (degrees, wrapped to [0, 360)) of shift ``a``: db_start + a * 360/n - query_start."""
    return np.mod(db_start_deg + np.asarray(shift) * 360.0 / n - query_start_deg, 360.0)
