"""The Clebsch variational integrator of the (generalised) free rigid body, seed 002 §4.1:
Theorem 28 with the corrected transpose and Example 31 (eqs. 18–19), Cayley difference map, on
SO(3) or SO(n); and its reduced Lie–Poisson form (seed 002 spec §2.2).

Pairing ⟨A, B⟩ = ½tr(AᵀB) (the coordinate dot product of :mod:`vi_jax.lie`), l(X) = ½⟨X, 𝕀X⟩
with the inertia operator 𝕀 of a :class:`~vi_jax.models.RigidBody`, so δl/δX = 𝕀X.
A_k = cay(hX^k), S_k = (A_k + I)/2 and (T_A loḡ)ᵀ(M) = S⁻ᵀMS⁻ᵀ (Example 31).

Clebsch (Q, P) form, M^k = Q^kᵀP^k:
  (18)  𝕀X^k = vee(skew M^k);   (19)  Q^{k+1} = Q^k A_k;
  (13)  (T_{A_{k+1}}loḡ)ᵀ(M^{k+1}) = A_kᵀ(T_{A_k}loḡ)ᵀ(M^k) A_{k+1}^{−ᵀ}  (the paper omits the ᵀ),
        solved with (18) for X^{k+1} by Newton; then P^{k+1} = Q^{k+1,−ᵀ}M^{k+1}.
Lie–Poisson form, with the discrete Legendre momentum μ̃ = (dcay⁻¹_{hX})*𝕀X
= (I + hX̂/2)(𝕀X)^(I − hX̂/2) (spec §2.2; Cor. 30 corrected):
  solve μ̃(X^k) = μ̃_k;   Q^{k+1} = Q^k A_k;   μ̃_{k+1} = Ad*_{A_k}μ̃_k = A_kᵀ μ̃_k A_k.
Both reproduce the same X^k; ‖μ̃‖, the spectrum of μ̃ and the spatial momentum Q μ̃ Qᵀ are conserved
exactly, l's momentum 𝕀X is not (O(h²)). Both start from the consistent initialisation μ̃₀ = 𝕀Ω(0)
(spec §3 (b)), so that (Q^k, μ̃_k) ≈ (Q(t_k), 𝕀Ω(t_k)) at order 2. The scheme is the DEP–Cayley step
of :func:`vi_jax.simulate` (order 1 or 2; they coincide without potential), Remark 32.

Everything is jittable, vmappable and differentiable (Newton with implicit-function gradients).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _validation as val
from ..engine._simulate import NewtonFailure
from ..solvers import RESULT_MESSAGES, SUCCESS, newton_root
from .._system import State
from ..models._rigid_body import RigidBody

FORMS = ("lie_poisson", "clebsch")


class ClebschSolution(eqx.Module):
    """Nodes k = 0..n_steps (leading axis): ``t``; ``Q`` (= ``R``); ``omega`` = X^k;
    ``Pi`` = 𝕀X^k = Proj(QᵀP) (the Clebsch momentum map, eq. 18); ``mu`` = μ̃_k (the discrete
    Legendre momentum); ``P`` (the ambient multiplier, ``form="clebsch"`` only, else None);
    ``spatial`` = Ad*_{Q⁻¹}μ̃ (coordinates of Q μ̃ Qᵀ); ``energy`` = ½X·𝕀X; Newton statistics of
    the solve for X^k: ``newton_iterations``, ``newton_residual`` (relative), ``result`` (0 = success).
    """

    t: jax.Array
    Q: jax.Array
    omega: jax.Array
    Pi: jax.Array
    mu: jax.Array
    P: jax.Array | None
    spatial: jax.Array
    energy: jax.Array
    newton_iterations: jax.Array
    newton_residual: jax.Array
    result: jax.Array

    @property
    def R(self):
        return self.Q

    @property
    def succeeded(self):
        return jnp.all(self.result == SUCCESS)


def _eye(body, dtype):
    return jnp.eye(body.group.matrix_size, dtype=dtype)


def discrete_legendre(body, h, omega):
    """μ̃ = (dcay⁻¹_{hX})*(𝕀X) = vee((I + hX̂/2)(𝕀X)^(I − hX̂/2)) (spec §2.2 and §3 vector form)."""
    G = body.group
    half = 0.5 * h * G.hat(omega)
    eye = _eye(body, omega.dtype)
    return G.vee((eye + half) @ G.hat(body.inertia @ omega) @ (eye - half))


def inverse_discrete_legendre(body, h, mu, guess, *, rtol, max_iterations=20):
    """X with :func:`discrete_legendre` (body, h, X) = μ by Newton from ``guess``; returns
    (X, :class:`~vi_jax.solvers.NewtonStats`)."""

    def residual(x):
        value = discrete_legendre(body, h, x)
        return value - mu, jnp.max(jnp.abs(mu)) + jnp.max(jnp.abs(value))

    return newton_root(residual, guess, rtol=rtol, max_iterations=max_iterations)


def lie_poisson_step(body, h, Q, mu, omega, *, rtol, max_iterations=20):
    """Node k ↦ k + 1 of the Lie–Poisson form: (Q^k, μ̃_k, X^k) with μ̃(X^k) = μ̃_k ↦
    (Q^{k+1}, μ̃_{k+1}, X^{k+1}, stats)."""
    G = body.group
    A = G.cay(h * omega)
    mu_next = G.Ad_dual_inv(G.inverse(A), mu)
    omega_next, stats = inverse_discrete_legendre(body, h, mu_next, omega, rtol=rtol, max_iterations=max_iterations)
    return Q @ A, mu_next, omega_next, stats


def _log_bar_tangent_dual(body, h, omega, M):
    """(T_A loḡ)ᵀ(M) = S⁻ᵀMS⁻ᵀ at A = cay(hX), with S⁻¹ = I − ½loḡ(A) = I − hX̂/2 (Example 31).
    Forming S⁻¹ by a linear solve instead biases ‖μ̃‖ by ~0.1 ulp per step (drift 3e-13 over 10⁴)."""
    half = 0.5 * h * body.group.hat(omega)
    S_inv_T = _eye(body, M.dtype) + half
    return S_inv_T @ M @ S_inv_T


def clebsch_step(body, h, Q, P, omega, *, rtol, max_iterations=20):
    """Node k ↦ k + 1 of Theorem 28 / Example 31 with the corrected transpose:
    (Q^k, P^k, X^k) ↦ (Q^{k+1}, P^{k+1}, X^{k+1}, stats), where X^k solves (18) (to the Newton
    tolerance: carrying it, rather than re-solving (18), keeps the congruences of (13) exactly
    orthogonal, so ‖μ̃‖ is conserved to round-off)."""
    G = body.group
    A = G.cay(h * omega)
    Q_next = Q @ A
    known = A.T @ _log_bar_tangent_dual(body, h, omega, Q.T @ P)  # A_kᵀ (T_{A_k}loḡ)ᵀ(M^k)
    eye = _eye(body, Q.dtype)

    def momentum(x):
        """M^{k+1} = [(T_{A_{k+1}}loḡ)ᵀ]⁻¹(known · A_{k+1}^{−ᵀ}) with A^{−ᵀ} = A on SO(n)."""
        A1 = G.cay(h * x)
        St = 0.5 * (A1 + eye).T
        return St @ known @ A1 @ St

    def residual(x):
        target = G.vee(momentum(x))
        value = body.inertia @ x
        return value - target, jnp.max(jnp.abs(target)) + jnp.max(jnp.abs(value))

    omega_next, stats = newton_root(residual, omega, rtol=rtol, max_iterations=max_iterations)
    # P = Q^{−ᵀ}M as in (13), not QM: Q drifts off SO(n) at round-off, and QᵀQM ≠ M would
    # feed that drift back into M at every step.
    return Q_next, jnp.linalg.solve(Q_next.T, momentum(omega_next)), omega_next, stats


def _validate(body, x0, h, n_steps, form):
    if not isinstance(body, RigidBody):
        raise ValueError(f"body: expected a vi_jax.models.RigidBody, got {type(body).__name__}")
    if not isinstance(x0, State):
        raise ValueError(f"x0: expected a vi_jax.State (e.g. body.initial_state()), got {type(x0).__name__}")
    G = body.group
    g0 = val.check_finite("x0.g", val.as_array("x0.g", x0.g, (G.matrix_size, G.matrix_size)))
    val.check_on_group("x0.g", G, g0)
    val.check_finite("x0.xi", val.as_array("x0.xi", x0.xi, (G.dim,)))
    if x0.q is not None or x0.qdot is not None:
        raise ValueError("x0: the free rigid body has no additional dynamics; expected x0.q = x0.qdot = None")
    val.check_finite("body.inertia", body.inertia)
    val.check_positive_scalar("h", h)
    val.check_int("n_steps", n_steps, 1)
    val.check_choice("form", form, FORMS)


def simulate(body, x0: State, h, n_steps: int, *, form="lie_poisson", rtol=None, max_iterations=20, throw=True):
    """``n_steps`` Clebsch–Cayley steps of the free rigid ``body`` from continuous data
    ``x0`` = (Q(0), Ω(0)), with μ̃₀ = 𝕀Ω(0). ``form``: "lie_poisson" (reduced, explicit momentum
    update) or "clebsch" (the (Q, P) scheme of Theorem 28). ``throw=True`` raises
    :class:`~vi_jax.NewtonFailure` when a solve fails (an equinox runtime error under ``jit``).
    Returns a :class:`ClebschSolution`."""
    _validate(body, x0, h, n_steps, form)
    dtype = jnp.result_type(x0.g, x0.xi, h, float)  # the working precision (float32 runs too)
    rtol = float(64 * jnp.finfo(dtype).eps) if rtol is None else float(val.check_positive_scalar("rtol", rtol))
    max_iterations = val.check_int("max_iterations", max_iterations, 1)
    body = jax.tree.map(lambda x: x.astype(dtype) if eqx.is_inexact_array(x) else x, body)
    Q0, omega0, h = (jnp.asarray(x, dtype) for x in (x0.g, x0.xi, h))
    sol = _simulate(body, Q0, omega0, h, n_steps, form, rtol, max_iterations)
    return _check(sol) if throw else sol


@eqx.filter_jit
def _simulate(body, Q0, omega0, h, n_steps, form, rtol, max_iterations):
    G = body.group
    opts = dict(rtol=rtol, max_iterations=max_iterations)
    omega, stats0 = inverse_discrete_legendre(body, h, body.inertia @ omega0, omega0, **opts)
    if form == "clebsch":
        state0 = (Q0, Q0 @ G.hat(body.inertia @ omega), omega)
        step_fn = clebsch_step
    else:
        state0 = (Q0, body.inertia @ omega0, omega)
        step_fn = lie_poisson_step

    def step(state, _):
        new = step_fn(body, h, *state, **opts)
        return new[:3], new

    _, (Qs, moms, omegas, stats) = jax.lax.scan(step, state0, None, length=n_steps)
    cat = lambda first, rest: jnp.concatenate([jnp.asarray(first)[None], rest])  # noqa: E731
    Q = cat(Q0, Qs)
    omega = cat(omega, omegas)
    stats = jax.tree.map(cat, stats0, stats)
    if form == "clebsch":
        P = cat(state0[1], moms)
        mu = jax.vmap(lambda x: discrete_legendre(body, h, x))(omega)
    else:
        P = None
        mu = cat(state0[1], moms)
    Pi = omega @ body.inertia.T
    return ClebschSolution(
        t=h * jnp.arange(n_steps + 1, dtype=h.dtype),
        Q=Q,
        omega=omega,
        Pi=Pi,
        mu=mu,
        P=P,
        spatial=jax.vmap(G.Ad_dual_inv)(Q, mu),
        energy=0.5 * jnp.sum(omega * Pi, axis=-1),
        newton_iterations=stats.iterations,
        newton_residual=stats.residual,
        result=stats.result,
    )


def _check(sol: ClebschSolution) -> ClebschSolution:
    failed = sol.result != SUCCESS
    if val.is_concrete(failed):
        if bool(jnp.any(failed)):
            k = int(np.argmax(np.asarray(failed)))
            code = int(sol.result[k])
            raise NewtonFailure(
                f"Clebsch step failed at node {k} (t ≈ {float(sol.t[k]):.6g}): {RESULT_MESSAGES.get(code, code)}; "
                f"relative residual {float(sol.newton_residual[k]):.3g}. Reduce h, raise max_iterations, "
                "or pass throw=False to inspect the ClebschSolution."
            )
        return sol
    return eqx.error_if(sol, jnp.any(failed), "Clebsch step failed (Newton did not converge); pass throw=False")
