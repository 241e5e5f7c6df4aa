"""frictionfit's Levenberg-Marquardt as an optimistix least-squares solver.

``optx.least_squares(fn, BatchedLevenbergMarquardt(), y0)`` solves one problem;
``fit_trials`` and the whole-measurement fits run it, like any optimistix
least-squares solver, in refilled pools of slots (:mod:`frictionfit.fit._optx`).
``y0`` must be a 1-D array.

Each step costs one forward-mode Jacobian (``jax.jacfwd``: few parameters, thousands
of residuals), from which only the ``p x p`` normal matrix ``J^T J`` and gradient
``J^T r`` are kept (``J^T J`` at the solution is in ``stats["jtj"]``; a problem may
supply them itself, ``normal``); the damped
normal equations, with Marquardt scaling (running max of ``diag(J^T J)``, as in
MINPACK), are solved with ``lineax.Cholesky``.

Damping (Nielsen's rule): an accepted step scales ``lambda`` by
``max(1/3, 1 - (2 g - 1)^3)``, ``g`` the gain ratio of actual to predicted cost
decrease, so a step that the linear model predicted well lowers the damping and a
poor one keeps it; a rejected step multiplies it by :data:`REJECT_GROWTH`.

Convergence (MINPACK-like): a step (accepted or not) that changes the cost by less than
``ftol`` relatively while the damping is at most 1 (a near Gauss-Newton step, not a tiny
damped one; a rejected one must also be predicted to gain less than that), or that moves
every unconstrained parameter by less than ``rtol (1 + |u|)``; or a gradient whose
largest cosine with a Jacobian column is below ``atol``; or a damping that has grown past
``LAMBDA_MAX`` (no downhill step exists: a local minimum to working precision).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from frictionfit.fit._numerics import normal_equations

__all__ = ["DATA_ATOL", "DATA_FTOL", "DATA_RTOL", "BatchedLevenbergMarquardt"]

RUNNING, CONVERGED, NONFINITE = 0, 1, 2
#: Step and cost tolerances of frictionfit's fits to noisy measurements: a relative change of
#: 1e-6 in the cost is far below what their noise lets the data determine. The solver's own
#: defaults are stricter, for problems that are solved to many digits.
DATA_RTOL, DATA_FTOL = 1e-8, 1e-6
#: The absolute step tolerance (``atol``) the optimistix solvers are given beside ``DATA_RTOL``.
DATA_ATOL = 1e-8
#: A converged point where a parameter's ``J^T J`` diagonal is below this share of the
#: largest diagonal seen (its column ``1 / eps`` times shorter: it does not act in float64)
#: is reported ``singular``, unless the problem says that such a parameter sits on a bound
#: (``options={"bounded": True}``: frictionfit's logistic coordinates).
VANISHED = float(jnp.finfo(jnp.float64).eps) ** 2
LAMBDA_MAX = 1e10
#: Damping growth after a rejected step. Each step costs a full Jacobian, accepted or
#: not, so a rejected step is expensive: growing fast wastes fewer.
REJECT_GROWTH = 10.0


class _State(NamedTuple):
    u: jax.Array  # (p,) accepted point
    cand: jax.Array  # (p,) point evaluated next
    cost: jax.Array  # () 0.5 |r|^2 at u; inf before the first evaluation
    jtj: jax.Array  # (p, p) at u
    grad: jax.Array  # (p,) J^T r at u
    scale: jax.Array  # (p,) Marquardt scaling, running max of diag(J^T J)
    lam: jax.Array  # ()
    steps: jax.Array  # () int
    code: jax.Array  # () int, RUNNING while active


def _damped_step(jtj, grad, scale, lam):
    """Solve ``(J^T J + lam diag(scale)) d = -J^T r`` (Cholesky)."""
    op = lx.MatrixLinearOperator(jtj + jnp.diag(lam * scale), lx.positive_semidefinite_tag)
    sol = lx.linear_solve(op, -grad, lx.Cholesky(), throw=False)
    return sol.value


def _iteration(s: _State, evaluated, ftol: float, xtol: float, gtol: float,
               lambda0: float) -> _State:
    """One LM iteration, given ``evaluated = (cost, J^T J, J^T r)`` at ``s.cand``: accept
    or reject the candidate, update the damping and the scaling, test convergence, and
    propose the next candidate."""
    active = s.code == RUNNING
    cost_c, jtj_c, grad_c = evaluated
    finite = jnp.isfinite(cost_c) & jnp.all(jnp.isfinite(grad_c)) & jnp.all(jnp.isfinite(jtj_c))
    fresh = jnp.isinf(s.cost)
    accept = active & finite & (cost_c <= s.cost)
    decrease = jnp.where(fresh, jnp.inf, s.cost - cost_c)
    # Gain ratio: actual over predicted decrease of the step (its linear model).
    d = s.cand - s.u
    predicted = -(d @ s.grad + 0.5 * d @ (s.jtj @ d))
    gain = jnp.where(predicted > 0, decrease / jnp.maximum(predicted, 1e-300), 0.0)
    small_move = jnp.all(jnp.abs(s.cand - s.u) <= xtol * (1.0 + jnp.abs(s.u)))
    u = jnp.where(accept, s.cand, s.u)
    cost = jnp.where(accept, cost_c, s.cost)
    jtj = jnp.where(accept, jtj_c, s.jtj)
    grad = jnp.where(accept, grad_c, s.grad)
    diag = jnp.diagonal(jtj)
    scale = jnp.where(accept, jnp.maximum(s.scale, diag), s.scale)
    shrink = jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * jnp.clip(gain, 0.0, 1.0) - 1.0) ** 3)
    lam = jnp.where(accept, jnp.maximum(s.lam * shrink, 1e-12), s.lam * REJECT_GROWTH)
    lam = jnp.where(accept & fresh, lambda0, lam)
    # MINPACK gtol: largest cosine between the residual and a Jacobian column.
    cosine = jnp.max(jnp.abs(grad) / jnp.sqrt(jnp.maximum(diag * 2.0 * cost, 1e-300)))
    # At an optimum of a non-smooth residual every step is rejected: a rejected step whose
    # predicted and actual changes are both below ftol (at near Gauss-Newton damping), or
    # that is below xtol, is converged, rather than growing the damping to LAMBDA_MAX one
    # full Jacobian at a time.
    tiny = (predicted <= ftol * s.cost) & (jnp.abs(decrease) <= ftol * s.cost)
    stalled = ~accept & ~fresh & finite & (((s.lam <= 1.0) & tiny) | small_move)
    converged = active & (
        (accept & ~fresh & (((decrease <= ftol * cost) & (s.lam <= 1.0)) | small_move))
        | stalled
        | (jnp.isfinite(cost) & (cosine <= gtol))
        | (lam > LAMBDA_MAX)
    )
    code = jnp.where(active & fresh & ~finite, NONFINITE, s.code)
    code = jnp.where((code == RUNNING) & converged, CONVERGED, code)
    cand = u + _damped_step(jtj, grad, jnp.maximum(scale, 1e-300), lam)
    return _State(u, cand, cost, jtj, grad, scale, lam, s.steps + active, code)


class BatchedLevenbergMarquardt(optx.AbstractLeastSquaresSolver):
    """Levenberg-Marquardt with Nielsen's damping and Marquardt scaling.

    The default tolerances solve certified reference problems: on the NIST StRD problems
    it is tested on (both starts, ``max_steps=2000``) every parameter reaches at least 4
    certified digits, except BoxBOD from start 1, which ends on a plateau where one
    parameter no longer acts and says so (``singular``; MINPACK calls it converged); with
    ``max_steps`` too small it says so rather than stopping early. Fits to noisy data may
    pass looser ones (:data:`DATA_RTOL`, :data:`DATA_FTOL`).

    Parameters
    ----------
    rtol : float
        Relative step tolerance: converged when every component moves by less than
        ``rtol (1 + |y|)`` (MINPACK's ``xtol``).
    atol : float
        Gradient tolerance: converged when the largest cosine between the residual and
        a Jacobian column falls below it (MINPACK's ``gtol``).
    ftol : float
        Converged when an accepted, nearly undamped step lowers the cost by less than
        this, relatively.
    lambda0 : float
        Damping after the first evaluation.
    norm : callable
        Kept for optimistix's interface; the tests above do not use it.
    normal : callable, optional
        ``normal(y, args) -> (|r|^2 / 2, J^T J, J^T r)``: the problem's own normal
        equations in place of a forward-mode Jacobian of ``fn`` (a model that forms them
        faster; ``fn``'s aux is then taken from ``fn`` itself).

    Examples
    --------
    >>> import jax.numpy as jnp, optimistix as optx
    >>> fn = lambda y, x: y[0] * (1 - jnp.exp(-y[1] * x)) - 2 * (1 - jnp.exp(-0.5 * x))
    >>> sol = optx.least_squares(fn, BatchedLevenbergMarquardt(), jnp.array([1.0, 1.0]),
    ...                          args=jnp.linspace(0.1, 5, 20))
    >>> [round(float(v), 6) for v in sol.value]
    [2.0, 0.5]
    """

    rtol: float = 1e-12
    atol: float = 1e-10
    ftol: float = 1e-14
    lambda0: float = 1e-3
    norm: Callable = optx.max_norm
    normal: Callable | None = None

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        if jnp.ndim(y) != 1:
            raise ValueError(f"BatchedLevenbergMarquardt needs a 1-D y0, got shape "
                             f"{jnp.shape(y)}")
        p, dtype = y.shape[0], y.dtype
        state = _State(u=y, cand=y, cost=jnp.array(jnp.inf, dtype),
                       jtj=jnp.zeros((p, p), dtype), grad=jnp.zeros(p, dtype),
                       scale=jnp.zeros(p, dtype), lam=jnp.array(self.lambda0, dtype),
                       steps=jnp.array(0), code=jnp.array(RUNNING))
        return state, jax.tree_util.tree_map(jnp.zeros_like, aux_struct)

    def step(self, fn, y, args, options, state, tags):
        s, _ = state
        if self.normal is None:
            evaluated, aux = normal_equations(lambda u: fn(u, args), s.cand, has_aux=True)
        else:
            evaluated, aux = self.normal(s.cand, args), fn(s.cand, args)[1]
        s = _iteration(s, evaluated, ftol=self.ftol, xtol=self.rtol, gtol=self.atol,
                       lambda0=self.lambda0)
        return s.u, (s, aux), aux

    def terminate(self, fn, y, args, options, state, tags):
        s, _ = state
        result = optx.RESULTS.where(s.code == NONFINITE, optx.RESULTS.nonlinear_divergence,
                                    optx.RESULTS.successful)
        if not options.get("bounded", False):
            # a parameter whose column has vanished does not act: it ran off to a plateau
            # (or never acted), so the point is no isolated minimum
            vanished = jnp.any(jnp.diagonal(s.jtj) <= VANISHED * jnp.max(s.scale))
            result = optx.RESULTS.where((s.code == CONVERGED) & vanished,
                                        optx.RESULTS.singular, result)
        return s.code != RUNNING, result

    def postprocess(self, fn, y, aux, args, options, state, tags, result
                    ) -> tuple[Any, Any, dict[str, Any]]:
        s, _ = state
        return s.u, aux, {"steps": s.steps, "jtj": s.jtj, "cost": s.cost}
