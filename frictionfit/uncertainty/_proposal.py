"""Metropolis-Hastings proposals for emcee, fitted per trial, applied to many trials at once.

The contact model's posteriors are curved in a few directions (stiffness,
movement duration and slip length trade off along a ridge), so a single t at the
Laplace mode is a poor independence proposal there. Each trial's
:class:`Proposal` is fitted to the draws of a short pilot run instead: a
:class:`RidgeMap` that straightens the ridge, a multivariate t in the
straightened coordinates, and a *defensive* share of the Laplace t, which keeps
the ratio target / proposal bounded in the tails (the independence sampler
cannot get stuck far out). The proposal only changes how fast the chain mixes,
never its stationary distribution (the Metropolis-Hastings ratio includes it).

:class:`Proposals` stacks the proposals of many trials into arrays, so that one
vectorised NumPy call draws and scores the walkers of every trial.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import gammaln

__all__ = ["MultivariateT", "Proposal", "Proposals", "RidgeMap"]


@dataclass(frozen=True)
class MultivariateT:
    """A multivariate t: ``mean (p,)``, scale matrix ``scale (p, p)`` (the covariance is
    ``df / (df - 2)`` times it) and degrees of freedom ``df``."""

    mean: np.ndarray
    scale: np.ndarray
    df: float = 5.0

    @classmethod
    def with_covariance(cls, mean, cov, df: float) -> MultivariateT:
        """The t with covariance ``cov`` (``df > 2``)."""
        return cls(np.asarray(mean, dtype=np.float64), np.asarray(cov) * (df - 2) / df, df)


class RidgeMap:
    """A triangular, volume-preserving bijection that straightens a curved ridge.

    ``z_j = x_j - g_j(x_r)`` for every ``j != r`` and ``z_r = x_r``, where
    ``g_j`` is a polynomial (degree ``deg``) fitted by least squares to draws. The
    Jacobian is unit lower-triangular, so densities carry over unchanged:
    ``q_x(x) = q_z(T(x))``. The pivot ``r`` is the coordinate whose map leaves the
    smallest Gaussian entropy (log det of the covariance of ``z``).
    """

    def __init__(self, r: int, coef: np.ndarray, centre: float, scale: float):
        self.r, self.coef, self.centre, self.scale = r, coef, centre, scale

    def _basis(self, s: np.ndarray) -> np.ndarray:
        v = (s - self.centre) / self.scale
        return v[..., None] ** np.arange(1, self.coef.shape[0] + 1)

    def forward(self, x: np.ndarray) -> np.ndarray:
        return x - self._basis(x[..., self.r]) @ self.coef

    def inverse(self, z: np.ndarray) -> np.ndarray:
        return z + self._basis(z[..., self.r]) @ self.coef

    @classmethod
    def identity(cls, p: int, deg: int = 2) -> RidgeMap:
        return cls(0, np.zeros((deg, p)), 0.0, 1.0)

    @classmethod
    def fit(cls, draws: np.ndarray, deg: int = 2) -> RidgeMap:
        """The best map for ``draws (n, p)``; the identity if none straightens them."""
        n, p = draws.shape
        best, best_ld = cls.identity(p, deg), np.linalg.slogdet(np.cov(draws, rowvar=False))[1]
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


@dataclass(frozen=True)
class Proposal:
    """One trial's proposal: ``(1 - w) t_inner(T(x)) + w t_laplace(x)``."""

    ridge: RidgeMap
    inner: MultivariateT
    laplace: MultivariateT
    weight: float

    @classmethod
    def from_laplace(cls, mean, cov, df: float = 5.0) -> Proposal:
        """The Laplace t alone (the pilot's first stage): scale ``cov``, ``df``."""
        t = MultivariateT(np.asarray(mean, dtype=np.float64), np.asarray(cov), df)
        return cls(RidgeMap.identity(t.mean.size), t, t, 0.0)

    @classmethod
    def fit(cls, draws: np.ndarray, laplace: MultivariateT, *, weight: float = 0.2,
            df: float = 8.0, inflate: float = 1.2, deg: int = 2) -> Proposal:
        """Fit to ``draws (n, p)``: a ridge map, then a t with ``df`` whose covariance is
        ``inflate`` times the straightened draws'; ``weight`` of the Laplace t mixed in."""
        draws = draws[np.all(np.isfinite(draws), axis=1)]
        ridge = RidgeMap.fit(draws, deg) if deg > 0 else RidgeMap.identity(draws.shape[1])
        z = ridge.forward(draws)
        inner = MultivariateT.with_covariance(z.mean(axis=0), inflate * np.cov(z, rowvar=False), df)
        return cls(ridge, inner, laplace, weight)


class Proposals:
    """The :class:`Proposal` of each of ``m`` trials, stacked: walkers ``(m, W, p)``."""

    def __init__(self, proposals: list[Proposal]):
        self.m, self.p = len(proposals), proposals[0].inner.mean.size
        deg = max(q.ridge.coef.shape[0] for q in proposals)
        self.r = np.array([q.ridge.r for q in proposals])
        self.coef = np.stack([np.pad(q.ridge.coef, ((0, deg - q.ridge.coef.shape[0]), (0, 0)))
                              for q in proposals])
        self.centre = np.array([q.ridge.centre for q in proposals])[:, None]
        self.scale = np.array([q.ridge.scale for q in proposals])[:, None]
        self.inner = _StackedT([q.inner for q in proposals])
        self.laplace = _StackedT([q.laplace for q in proposals])
        w = np.array([q.weight for q in proposals])
        with np.errstate(divide="ignore"):  # weight 0 or 1: that part drops out
            self.log_w = np.log(w)[:, None], np.log1p(-w)[:, None]
        self.weight = w[:, None]

    def _basis(self, x: np.ndarray) -> np.ndarray:
        v = (x[np.arange(self.m), :, self.r] - self.centre) / self.scale
        return v[..., None] ** np.arange(1, self.coef.shape[1] + 1)

    def forward(self, x: np.ndarray) -> np.ndarray:
        """Straightened coordinates ``T(x)`` of walkers ``x (m, W, p)``."""
        return x - self._basis(x) @ self.coef

    def inverse(self, z: np.ndarray) -> np.ndarray:
        return z + self._basis(z) @ self.coef

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """Log density ``(m, W)`` at walkers ``x (m, W, p)``."""
        return np.logaddexp(self.log_w[1] + self.inner.logpdf(self.forward(x)),
                            self.log_w[0] + self.laplace.logpdf(x))

    def rvs(self, n: int, random: np.random.RandomState) -> np.ndarray:
        """``n`` draws per trial, ``(m, n, p)``."""
        x = self.inverse(self.inner.rvs(n, random))
        from_laplace = random.rand(self.m, n) < self.weight
        if from_laplace.any():
            x = np.where(from_laplace[..., None], self.laplace.rvs(n, random), x)
        return x

    def independence(self, coords: np.ndarray, random: np.random.RandomState):
        """emcee ``MHMove`` proposal: independence MH, walkers ``(m * W, p)`` by trial."""
        x = coords.reshape(self.m, -1, self.p)
        new = self.rvs(x.shape[1], random)
        return new.reshape(coords.shape), (self.logpdf(x) - self.logpdf(new)).ravel()

    def ridge_walk(self, coords: np.ndarray, random: np.random.RandomState,
                   step: float = 0.5):
        """emcee ``MHMove`` proposal: a Gaussian random walk in the straightened coordinates,
        ``step**2`` times the inner t's covariance (symmetric: ``T`` preserves volume).
        It moves walkers that the independence proposal leaves stuck in the far tails."""
        z = self.forward(coords.reshape(self.m, -1, self.p))
        z = z + step * self.inner.cov_chol_rvs(z.shape[1], random)
        return self.inverse(z).reshape(coords.shape), np.zeros(coords.shape[0])


class _StackedT:
    """``m`` multivariate t densities as arrays (log density and draws, vectorised)."""

    def __init__(self, ts: list[MultivariateT]):
        self.mean = np.stack([t.mean for t in ts])[:, None]
        self.chol = np.stack([_chol(t.scale) for t in ts])
        # inverse factors: a matrix product per call instead of m triangular solves
        self.inv_chol = np.linalg.inv(self.chol)
        self.df = np.array([t.df for t in ts], dtype=np.float64)[:, None]
        p = self.chol.shape[1]
        logdet = np.sum(np.log(np.einsum("mii->mi", self.chol)), axis=1)[:, None]
        self.const = (gammaln((self.df + p) / 2) - gammaln(self.df / 2)
                      - 0.5 * p * np.log(self.df * np.pi) - logdet)

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        z = np.einsum("mij,mwj->mwi", self.inv_chol, x - self.mean)
        p = x.shape[-1]
        return self.const - 0.5 * (self.df + p) * np.log1p(np.sum(z**2, axis=-1) / self.df)

    def rvs(self, n: int, random: np.random.RandomState) -> np.ndarray:
        m, p = self.chol.shape[:2]
        z = np.einsum("mij,mwj->mwi", self.chol, random.standard_normal((m, n, p)))
        g = random.chisquare(np.broadcast_to(self.df, (m, n))) / self.df
        return self.mean + z / np.sqrt(g)[..., None]

    def cov_chol_rvs(self, n: int, random: np.random.RandomState) -> np.ndarray:
        """``n`` zero-mean Gaussian draws per t with the t's covariance, ``(m, n, p)``."""
        m, p = self.chol.shape[:2]
        z = np.einsum("mij,mwj->mwi", self.chol, random.standard_normal((m, n, p)))
        return z * np.sqrt(self.df / (self.df - 2))[..., None]


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
