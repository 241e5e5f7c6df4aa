"""Independence proposals for emcee: a mixture of multivariate t densities.

The contact model's posteriors are skewed and curved in a few directions
(stiffness, movement duration and slip length trade off), so a single Gaussian
at the Laplace mode is a poor independence proposal there. :class:`TMixture`
is fitted to the draws of a short pilot run instead (a Gaussian mixture, its
components turned into t densities with ``df`` degrees of freedom and their
scales inflated a little), plus a *defensive* broad t component around the
draws' mean and covariance: the ratio target / proposal stays bounded in the
tails, so the independence sampler cannot get stuck far out. The proposal only
changes how fast the chain mixes, never its stationary distribution (the
Metropolis-Hastings ratio includes it).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
from scipy.special import gammaln

#: An emcee ``MHMove`` proposal function: ``(coords, random) -> (new coords, log q ratio)``.
Propose = Callable[[np.ndarray, np.random.RandomState], tuple[np.ndarray, np.ndarray]]

__all__ = ["MappedT", "TMixture", "independence_step", "ridge_walk_step"]


class TMixture:
    """A weighted mixture of multivariate t densities (sampling and log density).

    Parameters
    ----------
    weights : ndarray (K,)
    means : ndarray (K, p)
    covs : ndarray (K, p, p)
        Scale matrices (the covariance is ``df / (df - 2)`` times this).
    df : float or ndarray (K,)
    """

    def __init__(self, weights, means, covs, df=5.0):
        self.weights = np.asarray(weights, dtype=np.float64) / np.sum(weights)
        self.means = np.atleast_2d(np.asarray(means, dtype=np.float64))
        k, p = self.means.shape
        self.df = np.broadcast_to(np.asarray(df, dtype=np.float64), (k,)).copy()
        self.chols = np.stack([_chol(c) for c in np.asarray(covs, dtype=np.float64)])
        # inverse factors: a matrix product per density call instead of a triangular solve
        # (scipy's per-call overhead dominated the samplers' proposal cost)
        self._inv_chols = np.linalg.inv(self.chols)
        self._logdet = np.sum(np.log(np.einsum("kii->ki", self.chols)), axis=1)
        self._const = (gammaln((self.df + p) / 2) - gammaln(self.df / 2)
                       - 0.5 * p * np.log(self.df * np.pi) - self._logdet)

    @property
    def dim(self) -> int:
        return self.means.shape[1]

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """Log density at ``x (n, p)``."""
        x = np.atleast_2d(x)
        p = self.dim
        z = np.einsum("kij,knj->kni", self._inv_chols, x[None] - self.means[:, None])
        m = np.sum(z**2, axis=2)
        out = (np.log(self.weights) + self._const)[:, None] - 0.5 * (
            self.df + p)[:, None] * np.log1p(m / self.df[:, None])
        return np.logaddexp.reduce(out, axis=0)

    def rvs(self, n: int, random: np.random.RandomState) -> np.ndarray:
        """``n`` draws, shape ``(n, p)``."""
        comp = random.choice(len(self.weights), size=n, p=self.weights)
        z = random.standard_normal((n, self.dim))
        w = random.chisquare(self.df[comp]) / self.df[comp]
        return self.means[comp] + np.einsum("nij,nj->ni", self.chols[comp], z) / np.sqrt(w)[:, None]

    @classmethod
    def gaussian_t(cls, mean, cov, df: float = 5.0) -> TMixture:
        """One t component (the Laplace proposal)."""
        return cls([1.0], [mean], [cov], df)

    @classmethod
    def fit(cls, draws: np.ndarray, *, max_components: int = 3, inflate: float = 1.3,
            df: float = 6.0, defensive: float = 0.1, seed: int = 0) -> TMixture:
        """Fit to pilot ``draws (n, p)``: a Gaussian mixture (components chosen by BIC).

        Each component becomes a t with ``df`` and its covariance times
        ``inflate``; a defensive component (weight ``defensive``, ``df = 3``,
        twice the draws' covariance) keeps the tails heavy.
        """
        from sklearn.mixture import GaussianMixture

        draws = np.asarray(draws, dtype=np.float64)
        draws = draws[np.all(np.isfinite(draws), axis=1)]
        n, p = draws.shape
        mean = draws.mean(axis=0)
        cov = np.cov(draws, rowvar=False).reshape(p, p) + 1e-12 * np.eye(p)
        best, best_bic = None, np.inf
        # at least ~10 draws per parameter of a component's covariance
        k_max = max(1, min(max_components, n // (5 * p * (p + 3))))
        reg = 1e-6 * float(np.mean(np.diag(cov)))
        for k in range(1, k_max + 1):
            gm = GaussianMixture(k, covariance_type="full", reg_covar=reg, random_state=seed,
                                 n_init=1, max_iter=200)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    gm.fit(draws)
                except Exception:  # degenerate draws: keep the smaller mixture
                    break
            bic = gm.bic(draws)
            if bic < best_bic:
                best, best_bic = gm, bic
        if best is None:
            return cls([1.0], [mean], [inflate * cov], df)
        scale = inflate * (df - 2) / df  # t scale whose covariance is inflate x component's
        weights = np.concatenate([(1 - defensive) * best.weights_, [defensive]])
        means = np.concatenate([best.means_, mean[None]])
        covs = np.concatenate([scale * best.covariances_, 2.0 * cov[None]])
        dfs = np.concatenate([np.full(best.n_components, df), [3.0]])
        return cls(weights, means, covs, dfs)


class RidgeMap:
    """A triangular, volume-preserving bijection that straightens a curved ridge.

    ``z_j = x_j - g_j(x_r)`` for every ``j != r`` and ``z_r = x_r``, where
    ``g_j`` is a polynomial (degree ``deg``, no linear term needed but kept)
    fitted by least squares to draws. The Jacobian is unit lower-triangular, so
    densities carry over unchanged: ``q_x(x) = q_z(T(x))``. The pivot ``r`` is
    the coordinate whose map leaves the smallest Gaussian entropy (log det of
    the covariance of ``z``).
    """

    def __init__(self, r: int, coef: np.ndarray, centre: float, scale: float):
        self.r, self.coef, self.centre, self.scale = r, coef, centre, scale

    def _basis(self, s: np.ndarray) -> np.ndarray:
        v = (s - self.centre) / self.scale
        return np.stack([v**k for k in range(1, self.coef.shape[0] + 1)], axis=1)

    def forward(self, x: np.ndarray) -> np.ndarray:
        return x - self._basis(x[:, self.r]) @ self.coef

    def inverse(self, z: np.ndarray) -> np.ndarray:
        return z + self._basis(z[:, self.r]) @ self.coef

    @classmethod
    def fit(cls, draws: np.ndarray, deg: int = 2) -> RidgeMap | None:
        n, p = draws.shape
        best, best_ld = None, np.linalg.slogdet(np.cov(draws, rowvar=False))[1]
        for r in range(p):
            s = draws[:, r]
            centre, scale = float(np.mean(s)), float(np.std(s))
            if not scale > 0:
                continue
            m = cls(r, np.zeros((deg, p)), centre, scale)
            basis = np.column_stack([np.ones(n), m._basis(s)])
            coef = np.linalg.lstsq(basis, draws, rcond=None)[0][1:]
            coef[:, r] = 0.0
            m.coef = coef
            ld = np.linalg.slogdet(np.cov(m.forward(draws), rowvar=False))[1]
            if ld < best_ld:
                best, best_ld = m, ld
        return best


class MappedT:
    """Mixture ``(1 - w) * t(z = T(x)) + w * defensive(x)`` with a :class:`RidgeMap` ``T``."""

    def __init__(self, ridge: RidgeMap | None, inner: TMixture, defensive: TMixture,
                 weight: float):
        self.ridge, self.inner, self.defensive, self.w = ridge, inner, defensive, weight

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        z = x if self.ridge is None else self.ridge.forward(x)
        return np.logaddexp(np.log1p(-self.w) + self.inner.logpdf(z),
                            np.log(self.w) + self.defensive.logpdf(x))

    def rvs(self, n: int, random: np.random.RandomState) -> np.ndarray:
        z = self.inner.rvs(n, random)
        x = z if self.ridge is None else self.ridge.inverse(z)
        use_def = random.rand(n) < self.w
        if use_def.any():
            x[use_def] = self.defensive.rvs(int(use_def.sum()), random)
        return x

    @classmethod
    def fit(cls, draws: np.ndarray, defensive: TMixture, *, weight: float = 0.2,
            df: float = 8.0, inflate: float = 1.2, deg: int = 2) -> MappedT:
        draws = draws[np.all(np.isfinite(draws), axis=1)]
        ridge = RidgeMap.fit(draws, deg) if deg > 0 else None
        z = draws if ridge is None else ridge.forward(draws)
        cov = np.cov(z, rowvar=False) * inflate * (df - 2) / df
        return cls(ridge, TMixture.gaussian_t(z.mean(axis=0), cov, df), defensive, weight)


def _chol(c: np.ndarray) -> np.ndarray:
    c = 0.5 * (c + c.T)
    d = np.sqrt(np.maximum(np.diag(c), 1e-300))
    for jitter in (0.0, 1e-10, 1e-8, 1e-6, 1e-4):
        try:
            return np.linalg.cholesky(c + jitter * np.diag(d**2) + 1e-300 * np.eye(len(c)))
        except np.linalg.LinAlgError:
            continue
    w, v = np.linalg.eigh(c)  # last resort: clip the spectrum
    return np.linalg.cholesky((v * np.maximum(w, 1e-12 * w.max())) @ v.T)


def ridge_walk_step(proposal: MappedT, scale: float = 0.5) -> Propose:
    """Random-walk Metropolis proposal in the straightened coordinates ``z = T(x)``.

    The step is Gaussian with ``scale**2`` times the fitted covariance of ``z``; ``T``
    preserves volume, so the move is symmetric in ``x`` too. It moves walkers that
    the independence proposal leaves stuck in the posterior's far tails.
    """
    chol = proposal.inner.chols[0] * np.sqrt(proposal.inner.df[0] / (proposal.inner.df[0] - 2))
    ridge = proposal.ridge

    def propose(coords: np.ndarray, random: np.random.RandomState):
        z = coords if ridge is None else ridge.forward(coords)
        z = z + scale * random.standard_normal(z.shape) @ chol.T
        new = z if ridge is None else ridge.inverse(z)
        return new, np.zeros(coords.shape[0])

    return propose


def independence_step(proposal: TMixture | MappedT) -> Propose:
    """Independence Metropolis-Hastings proposal from ``proposal`` (exact for any target)."""

    def propose(coords: np.ndarray, random: np.random.RandomState):
        new = proposal.rvs(coords.shape[0], random)
        return new, proposal.logpdf(coords) - proposal.logpdf(new)

    return propose
