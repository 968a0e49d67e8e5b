"""The marching engine shared by the time march and the space march (seed 003 §§4, 5; spec §3).

Both marches solve the same equation with the roles of (t, ξ, μ) and (s, η, λ) exchanged. Along
the *evolution* direction (step h_e, velocity v, momentum m) with *transverse* nodes i (step h_t,
velocity w, momentum n), the DCEL (82) at node i of evolution row k reads

    m_i^k = p_i^k − (h_e/h_t)(n_i^k − q_i^k) + h_e f_i^k,
    p_i^k = Ad*_{τ(h_e v_i^{k−1})} m_i^{k−1},   q_i^k = Ad*_{τ(h_t w_{i−1}^k)} n_{i−1}^k,

with the free transverse boundary of (69)/(70): q_0 := 0 (no triangle before node 0) and
n_last := 0 (the last node is slaved, w_last = w_free with ∂ℓ/∂w(w_free) = 0: the ghost node of
the zero-traction condition, or the ghost row g^N = g^{N−1} of the space march).

With the triangle quadrature, m depends on v only and n on w only when ℓ is separable
(ℓ = K(ξ) − Φ(η), as eq. 95): each step is then one independent dim-r Newton solve per node
(block-diagonal Jacobian, spec §6), batched with ``vmap`` inside ``lax.scan``, with
implicit-function gradients (``newton_root``).
"""

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.core import Literal

from .. import _validation as val
from ..engine._compile_options import single_trajectory_jit
from ..solvers import RESULT_MESSAGES, SUCCESS, dense_solve, newton_root
from ._lagrangian import dual_Ad


def _ell(system, axis):
    """ℓ with the evolving velocity first."""
    if axis == "time":
        return system.lagrangian
    return lambda v, w: system.lagrangian(w, v)


def _depends_on_first(fn, x, y) -> bool:
    """Whether fn(x, y) depends on x, read off its jaxpr (conservatively through sub-jaxprs)."""
    jaxpr = jax.make_jaxpr(fn)(x, y).jaxpr
    dependent = {jaxpr.invars[0]}
    for eqn in jaxpr.eqns:
        if any(not isinstance(v, Literal) and v in dependent for v in eqn.invars):
            dependent.update(eqn.outvars)
    return any(not isinstance(v, Literal) and v in dependent for v in jaxpr.outvars)


def check_separable(system, dtype):
    """Raise unless ∂ℓ/∂ξ is independent of η and ∂ℓ/∂η of ξ (decided at trace time)."""
    x = jax.ShapeDtypeStruct((system.group.dim,), dtype)
    l_xi = lambda eta, xi: jax.grad(system.lagrangian, argnums=0)(xi, eta)  # noqa: E731
    l_eta = lambda xi, eta: jax.grad(system.lagrangian, argnums=1)(xi, eta)  # noqa: E731
    if _depends_on_first(l_xi, x, x) or _depends_on_first(l_eta, x, x):
        raise ValueError(
            "system: the marches need a separable Lagrangian density ℓ(ξ, η) = K(ξ) + V(η) "
            "(∂ℓ/∂ξ independent of η and ∂ℓ/∂η independent of ξ), which makes each step one "
            "independent solve per node; got a density that couples ξ and η"
        )


def cast_system(system, dtype):
    """The system with its floating-point array parameters in ``dtype``."""
    return jax.tree.map(lambda x: x.astype(dtype) if eqx.is_inexact_array(x) else x, system)


class Rows(eqx.Module):
    """Engine output per evolution row (leading axis) and transverse node (second axis)."""

    g: jax.Array  # configurations g_i^k
    p: jax.Array  # incoming evolution momentum p_i^k (the state of the one-step map)
    v: jax.Array  # evolution velocity v_i^k (solved)
    m: jax.Array  # evolution momentum m_i^k
    w: jax.Array  # transverse velocity w_i^k (w_last = w_free)
    n: jax.Array  # transverse momentum n_i^k (n_last = 0)
    iterations: jax.Array
    residual: jax.Array
    result: jax.Array


class Carry(eqx.Module):
    g: jax.Array
    p: jax.Array
    v: jax.Array  # Newton guess: the previous row's velocities
    k: jax.Array  # evolution index


class Engine(eqx.Module):
    """One march: the system, τ, the steps, the transverse free strain and the options."""

    system: eqx.Module
    tau: eqx.Module
    axis: str = eqx.field(static=True)
    h_e: jax.Array
    h_t: jax.Array
    w_free: jax.Array
    clamp_first: bool = eqx.field(static=True)
    force: object  # None or f(k, g) -> (nodes, r) body wrench densities
    rtol: float = eqx.field(static=True)
    max_iterations: int = eqx.field(static=True)

    @property
    def group(self):
        return self.system.group

    def evolution_momentum(self, v):
        """m(v) = (dτ⁻¹_{h_e v})* ∂ℓ/∂v."""
        l_v = jax.grad(_ell(self.system, self.axis), argnums=0)(v, jnp.zeros_like(v))
        return self.tau.dtau_inv_dual(self.group, self.h_e * v, l_v)

    def transverse_momentum(self, w):
        """n(w) = (dτ⁻¹_{h_t w})* ∂ℓ/∂w."""
        l_w = jax.grad(_ell(self.system, self.axis), argnums=1)(jnp.zeros_like(w), w)
        return self.tau.dtau_inv_dual(self.group, self.h_t * w, l_w)

    def transverse(self, g):
        """(w, n, q) at every node of a row, with the free transverse boundary."""
        G, tau = self.group, self.tau
        w = jax.vmap(lambda a, b: tau.tau_inv(G, G.inverse(a) @ b))(g[:-1], g[1:]) / self.h_t
        n = jax.vmap(self.transverse_momentum)(w)
        q = jax.vmap(lambda x, y: dual_Ad(G, tau.tau(G, self.h_t * x), y))(w, n)
        zero = jnp.zeros((1, G.dim), g.dtype)
        return (
            jnp.concatenate([w, self.w_free[None].astype(g.dtype)]),
            jnp.concatenate([n, zero]),
            jnp.concatenate([zero, q]),
        )

    def target(self, k, g, p):
        """c_i = p_i − (h_e/h_t)(n_i − q_i) + h_e f_i: the momentum each node must take."""
        w, n, q = self.transverse(g)
        c = p - (self.h_e / self.h_t) * (n - q)
        if self.force is not None:
            c = c + self.h_e * self.force(k, g)
        return c, w, n

    def solve(self, c, v0):
        """m(v_i) = c_i for every (unclamped) node: vmapped dim-r Newton with implicit tangents."""
        first = 1 if self.clamp_first else 0
        rest = jnp.max(jnp.abs(self.evolution_momentum(jnp.zeros_like(v0[0]))))
        solve = jax.vmap(_node_solve, in_axes=(None, 0, 0, None))
        v, (iterations, residual, result) = solve(self, c[first:], v0[first:], rest)
        stats = (iterations.astype(jnp.int32), residual, result.astype(jnp.int8))
        if first:
            v = jnp.concatenate([jnp.zeros_like(v0[:1]), v])
            stats = tuple(jnp.concatenate([jnp.zeros_like(x[:1]), x]) for x in stats)
        return v, stats

    def row(self, carry: Carry):
        """Solve evolution row k: (next carry, the row's output)."""
        G, tau = self.group, self.tau
        c, w, n = self.target(carry.k, carry.g, carry.p)
        v, stats = self.solve(c, carry.v)
        m = jax.vmap(self.evolution_momentum)(v)
        step = jax.vmap(lambda x: tau.tau(G, self.h_e * x))(v)
        out = Rows(carry.g, carry.p, v, m, w, n, *stats)
        p_next = jax.vmap(lambda s, y: dual_Ad(G, s, y))(step, m)
        cast = lambda x, like: x.astype(like.dtype)  # noqa: E731  (parameters of another precision)
        return Carry(cast(carry.g @ step, carry.g), cast(p_next, carry.p), cast(v, carry.v), carry.k + 1), out

    def legendre(self, k, g0, g1):
        """Discrete Legendre transform p⁰ from two rows g⁰, g¹ (−D₁ of the row Lagrangian over h_t):
        the p⁰ for which the first solved row reproduces g¹."""
        G, tau = self.group, self.tau
        v = jax.vmap(lambda a, b: tau.tau_inv(G, G.inverse(a) @ b))(g0, g1) / self.h_e
        m = jax.vmap(self.evolution_momentum)(v)
        _, n, q = self.transverse(g0)
        p = m + (self.h_e / self.h_t) * (n - q)
        if self.force is not None:
            p = p - self.h_e * self.force(k, g0)
        return p, v


def _node_residual(engine, c, v, rest):
    """m(v) − c and the size of the terms that cancel in it: |m(v)|, |c| and |m(0)| = |∂ℓ/∂v(0)|
    (``rest``: the pre-stress ℂE₆ inside λ(η) = −(dcay⁻¹)*ℂ(η − E₆) in the space march)."""
    m = engine.evolution_momentum(v)
    return m - c, jnp.maximum(jnp.max(jnp.abs(jnp.concatenate([m, c]))), rest)


@eqx.filter_custom_jvp
def _node_solve(engine, c, v0, rest):
    """The root v of m(v) = c by ``newton_root`` from v0; statistics as floats (differentiable
    outputs must be inexact). The tangent is the implicit-function theorem's, written here
    because ``newton_root``'s ``custom_root`` (integer statistics as aux) cannot be
    differentiated in JAX 0.10: its JVP rule gives the aux integer, not float0, tangents."""
    v, stats = newton_root(
        lambda z: _node_residual(engine, c, z, rest), v0, rtol=engine.rtol, max_iterations=engine.max_iterations
    )
    return v, (stats.iterations.astype(c.dtype), stats.residual, stats.result.astype(c.dtype))


@_node_solve.def_jvp
def _node_solve_jvp(primals, tangents):
    engine, c, v0, rest = primals
    t_engine, t_c, _, _ = tangents
    v, stats = _node_solve(engine, c, v0, rest)
    dynamic, static = eqx.partition(engine, eqx.is_inexact_array)
    t_dynamic = jax.tree.map(
        lambda x, t: None if x is None else (jnp.zeros_like(x) if t is None else t),
        dynamic,
        jax.tree.map(lambda _: None, dynamic) if t_engine is None else t_engine,
        is_leaf=lambda x: x is None,
    )
    t_c = jnp.zeros_like(c) if t_c is None else t_c
    residual = lambda d, cc: _node_residual(eqx.combine(d, static), cc, v, rest)[0]  # noqa: E731
    _, d_residual = jax.jvp(residual, (dynamic, c), (t_dynamic, t_c))
    jac = jax.jacfwd(lambda z: _node_residual(engine, c, z, rest)[0])(v)
    return (v, stats), (-dense_solve(jac, d_residual), jax.tree.map(jnp.zeros_like, stats))


def _advance(engine: Engine, carry: Carry, n_saved: int, save_every: int, n_total: int):
    """``n_saved`` rows, each followed by ``save_every − 1`` unsaved ones; the steps after row
    ``n_total·save_every`` are not counted in the statistics (the last row's successors)."""

    def chunk(carry, i):
        carry, out = engine.row(carry)
        if save_every > 1:

            def quiet(c, _):
                c, o = engine.row(c)
                return c, (jnp.max(o.iterations), jnp.max(o.residual), jnp.max(o.result))

            carry, (it, res, code) = jax.lax.scan(quiet, carry, None, length=save_every - 1)
            counted = i < n_total
            out = eqx.tree_at(
                lambda o: (o.iterations, o.residual, o.result),
                out,
                tuple(
                    jnp.where(counted, jnp.maximum(x, jnp.max(y)), x)
                    for x, y in ((out.iterations, it), (out.residual, res), (out.result, code))
                ),
            )
        return carry, out

    return jax.lax.scan(chunk, carry, carry.k // save_every + jnp.arange(n_saved))


_advance_jit = single_trajectory_jit(_advance)


def advance_loop(engine: Engine, carry: Carry, n_rows, save_every, capacity: int) -> Rows:
    """``_advance`` with traced counts (``n_rows`` ≤ ``capacity`` saved rows, ``save_every``),
    for concrete runs (a ``while`` loop: not reverse-differentiable): one program serves every
    length, and one copy of the row solve is compiled. Every step rewrites the current saved
    row: with its own output when it is saved, else with the worst Newton statistics so far.
    The buffer's rows past ``n_rows`` hold the starting row's configuration, momentum and
    velocities, zeros elsewhere (valid data for the diagnostics); the last saved row's
    successors are not computed."""
    proto = jax.eval_shape(lambda c: engine.row(c)[1], carry)
    fill = eqx.tree_at(
        lambda r: (r.g, r.p, r.v), jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), proto), (carry.g, carry.p, carry.v)
    )
    rows = jax.tree.map(lambda x: jnp.broadcast_to(x, (capacity,) + x.shape), fill)
    stats = lambda r: (r.iterations, r.residual, r.result)  # noqa: E731

    def step(k, state):
        carry, rows = state
        carry, out = engine.row(carry)
        i, saved = k // save_every, k % save_every == 0
        here = jax.tree.map(lambda buf: jax.lax.dynamic_index_in_dim(buf, i, 0, keepdims=False), rows)
        worst = tuple(jnp.maximum(x, jnp.max(y)) for x, y in zip(stats(here), stats(out)))
        new = jax.tree.map(lambda a, b: jnp.where(saved, a, b), out, eqx.tree_at(stats, here, worst))
        return carry, jax.tree.map(lambda buf, x: jax.lax.dynamic_update_index_in_dim(buf, x, i, 0), rows, new)

    return jax.lax.fori_loop(0, (n_rows - 1) * save_every + 1, step, (carry, rows))[1]


def run(engine: Engine, carry: Carry, n_steps: int, save_every: int, progress: bool = False) -> Rows:
    """Rows 0, s, 2s, …, n_steps (s = save_every) from the carry at row 0. Each row's velocities
    are solved, so the last row costs one more solve (and s − 1 uncounted steps) whose
    successors are not returned."""
    n_total = n_steps // save_every
    if not progress:
        return _advance(engine, carry, n_total + 1, save_every, n_total)[1]
    from tqdm.auto import tqdm

    n_rows = n_total + 1
    size = -(-n_rows // min(n_rows, 100))  # equal chunks: one compilation; the surplus rows are dropped
    parts = []
    with tqdm(total=n_steps, unit="step", desc=f"{engine.axis} march") as bar:
        for _ in range(-(-n_rows // size)):
            carry, rows = _advance_jit(engine, carry, size, save_every, n_total)
            parts.append(rows)
            bar.update(min(size * save_every, n_steps - bar.n))
    return jax.tree.map(lambda *xs: jnp.concatenate(xs)[:n_rows], *parts)


def free_strain(system, axis, dtype, rtol, iterations=8):
    """w_free with ∂ℓ/∂w(w_free) = 0, the slaved end's velocity (n_last = 0): Newton from w = 0
    (one step for a quadratic potential); NaN, hence a failed march, if it does not converge."""
    r = system.group.dim
    zero = jnp.zeros(r, dtype)
    l_w = lambda w: jax.grad(_ell(system, axis), argnums=1)(zero, w)  # noqa: E731
    w = jax.lax.fori_loop(0, iterations, lambda _, w: w - dense_solve(jax.jacfwd(l_w)(w), l_w(w)), zero)
    scale = jnp.maximum(jnp.max(jnp.abs(l_w(zero))), jnp.finfo(dtype).tiny)
    return jnp.where(jnp.max(jnp.abs(l_w(w))) <= rtol * scale, w, jnp.nan)


class MarchFailure(RuntimeError):
    """A node-wise Newton solve of a march that did not converge (``throw=True``)."""


def check_failure(obj, result, where, throw):
    """The first failed (row, node) of ``result`` (march rows, nodes), described by ``where(row, node)``:
    ``throw=True`` raises :class:`MarchFailure` (under ``jit``: an equinox runtime error);
    ``throw=False`` warns (outside ``jit``) and returns ``obj`` with its result codes."""
    failed = result != SUCCESS
    if val.is_concrete(failed):
        if bool(jnp.any(failed)):
            row, node = np.unravel_index(int(np.argmax(np.asarray(failed))), failed.shape)
            code = int(result[row, node])
            message = f"Newton failed at {where(int(row), int(node))}: {RESULT_MESSAGES.get(code, code)}"
            if throw:
                raise MarchFailure(
                    f"{message}. Reduce the step, check the data, or pass throw=False to inspect the result codes."
                )
            warnings.warn(f"{message}; the march is not valid beyond it (see .result).", stacklevel=3)
        return obj
    if throw:
        return eqx.error_if(obj, jnp.any(failed), "march: a node-wise Newton solve failed; pass throw=False to inspect")
    return obj
