"""The time march (spec §3, "forward time-march update"): Dirichlet data in time, zero traction
(eqs. 68–69, 82–83) or a clamped first node in space, optional forces (eq. 39).

Nodes a = 0..A−1 carry a triangle and a mass; node A is the massless free end, slaved by
λ_{A−1} = 0 (eq. 69), i.e. g_A = g_{A−1} τ(Δs η_free) with ∂ℓ/∂η(η_free) = 0.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from .. import _validation as val
from .._accuracy import warn_if_meaningless
from .._precision import full_precision
from .._saved_nodes import first_rows, saved_capacity
from ..engine._compile_options import single_trajectory_jit
from ..lie import difference_map
from . import _march
from ._lagrangian import AbstractCovariantSystem
from ._noether import spatial_sum, time_energy_density

BOUNDARIES = ("free-free", "clamped-free")


class TimeMarch(eqx.Module):
    """A time-marched field at the saved rows j = 0, s, 2s, …, n_steps (s = save_every).

    ``g`` (rows, A+1, d, d) with the free end as the last node; per massive node a < A:
    ``xi`` ξ_a^j, ``eta`` η_a^j (η_{A−1} = η_free), ``mu``, ``lam`` (per unit area, spec §3),
    ``p`` the incoming momentum Ad*_{τ(Δtξ^{j−1})}μ^{j−1} (the state of the time map; row 0: the
    Legendre start). ``momentum`` 𝖩_𝖫(j) = Σ_a Δs Ad*_{(g_a^j)⁻¹}μ_a^j (eq. 94), ``energy``
    E_L(j) = Σ_a Δs(⟨ℓ_ξ, ξ⟩ − ℓ) (spec §3; its band is O(Δt), K being taken at ξ^j). Newton
    statistics per (row, node), the worst over the steps since the previous saved row;
    ``result`` 0 = success.
    """

    t: jax.Array
    s: jax.Array
    g: jax.Array
    xi: jax.Array
    eta: jax.Array
    mu: jax.Array
    lam: jax.Array
    p: jax.Array
    momentum: jax.Array
    energy: jax.Array
    newton_iterations: jax.Array
    newton_residual: jax.Array
    result: jax.Array

    @property
    def succeeded(self):
        return jnp.all(self.result == 0)


def default_rtol(dtype):
    return float(64 * jnp.finfo(dtype).eps)


def validate_system(system):
    if not isinstance(system, AbstractCovariantSystem):
        raise ValueError(
            f"system: expected a covariant system (AbstractCovariantSystem), got {type(system).__name__}"
        )
    val.check_finite("system parameters", eqx.filter(system, eqx.is_inexact_array))
    _march.check_separable(system, jnp.result_type(float))
    return system.group


def validate_rows(name, group, g, n=None):
    """An array of n group elements (n ≥ 1; any n when None)."""
    d = group.matrix_size
    if jnp.ndim(g) != 3 or jnp.shape(g)[0] < 1:
        raise ValueError(f"{name}: expected shape (nodes, {d}, {d}) with nodes ≥ 1, got shape {jnp.shape(g)}")
    g = val.as_array(name, g, (jnp.shape(g)[0] if n is None else n, d, d))
    val.check_finite(name, g)
    if val.is_concrete(g):
        k = int(jnp.argmax(jax.vmap(group.membership_error)(g)))
        val.check_on_group(f"{name}[{k}]", group, g[k])
    return g


def _validate(system, g0, xi0, g1, dt, ds, n_steps, boundary, force, save_every):
    G = validate_system(system)
    g0 = validate_rows("g0", G, g0)
    nodes = g0.shape[0]
    if (xi0 is None) == (g1 is None):
        raise ValueError("xi0, g1: expected exactly one initial datum (velocities xi0 or the second row g1)")
    if xi0 is not None:
        xi0 = val.check_finite("xi0", val.as_array("xi0", xi0, (nodes, G.dim)))
    else:
        g1 = validate_rows("g1", G, g1, nodes)
    dt = val.check_positive_scalar("dt", dt)
    ds = val.check_positive_scalar("ds", ds)
    n_steps, save_every = val.check_steps(n_steps, save_every)
    val.check_choice("boundary", boundary, BOUNDARIES)
    if boundary == "clamped-free":
        if nodes < 2:
            raise ValueError(f"g0: a clamped-free march needs ≥ 2 nodes, got {nodes}")
        if g1 is not None and val.is_concrete((g0, g1)) and not bool(jnp.allclose(g1[0], g0[0], rtol=0, atol=1e-12)):
            raise ValueError("g1: the clamped node 0 must not move (g1[0] = g0[0])")
        if xi0 is not None and val.is_concrete(xi0) and bool(jnp.any(xi0[0] != 0)):
            raise ValueError(f"xi0: the clamped node 0 must be at rest, got xi0[0] = {xi0[0]}")
    if force is not None and not callable(force):
        raise ValueError(f"force: expected None or a function f(t, s, g) -> body wrench density, got {force!r}")
    return g0, xi0, g1, dt, ds, n_steps, save_every


def time_march(
    system,
    g0,
    *,
    xi0=None,
    g1=None,
    dt,
    ds,
    n_steps: int,
    boundary: str = "free-free",
    force=None,
    tau="cayley",
    save_every: int = 1,
    throw: bool = True,
    rtol=None,
    max_newton_iterations: int = 20,
    progress: bool = False,
) -> TimeMarch:
    """March the DCEL (82)–(83) forward in time from row 0.

    ``g0`` (A, d, d): the configurations of the massive nodes a = 0..A−1 at t = 0 (s_a = aΔs).
    Initial datum, exactly one of: ``xi0`` (A, r), the continuous body velocities, with the
    consistent start p⁰ = ∂ℓ/∂ξ(ξ(0, s_a)) (spec §3); or ``g1`` (A, d, d), the second row, with
    the discrete Legendre transform. ``boundary``: "free-free" (zero traction at both ends,
    eq. 83) or "clamped-free" (node 0 held at g0[0]). ``force(t, s, g)``: body wrench density
    (torque, force) per unit length, F̄¹ = ΔsΔt f (eq. 39). Each step is one vmapped dim-r Newton
    solve per node; jittable, vmappable and differentiable (implicit-function gradients). On
    concrete inputs one compiled program serves every ``n_steps`` and ``save_every`` with the
    same saved-row capacity (traced counts, as in ``vj.simulate``); under a transformation the
    loops have static lengths.
    ``throw=True`` raises :class:`MarchFailure` when a solve fails; ``throw=False`` records it in
    ``result``. Without ``force`` the march is conservative: an energy error that says the run is
    meaningless warns (:class:`vi_jax.AccuracyWarning`). ``progress=True`` shows a progress bar (outside ``jit``).
    """
    g0, xi0, g1, dt, ds, n_steps, save_every = _validate(
        system, g0, xi0, g1, dt, ds, n_steps, boundary, force, save_every
    )
    dtype = jnp.result_type(g0, dt, ds, *(x for x in (xi0, g1) if x is not None))
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    cast = lambda x: None if x is None else jnp.asarray(x, dtype)  # noqa: E731
    args = (cast(g0), cast(xi0), cast(g1), cast(dt), cast(ds))
    system = _march.cast_system(system, dtype)
    options = dict(
        boundary=boundary, force=force, tau=difference_map(tau),
        rtol=default_rtol(dtype) if rtol is None else float(rtol), max_iterations=int(max_newton_iterations),
    )
    with full_precision():
        if progress and val.is_eager((system, args)):
            engine, carry = _start_jit(system, *args, **options)
            rows = _march.run(engine, carry, n_steps, save_every, progress=True)
            sol = _assemble_jit(engine, rows, save_every)
        elif val.is_eager((system, args)):  # traced counts: one program for every length
            n_rows = n_steps // save_every + 1
            sol = _time_march_loop(system, *args, val.step_count(n_rows), val.step_count(save_every), capacity=saved_capacity(n_rows), **options)
            sol = eqx.tree_at(lambda m: m.s, first_rows(sol, n_rows), sol.s)
        else:
            sol = _time_march_jit(system, *args, n_steps=n_steps, save_every=save_every, **options)

    def where(row, node):
        rows = f"row {row}" if save_every == 1 else f"rows {row * save_every}..{(row + 1) * save_every - 1}"
        return f"time {rows} (t ≈ {row * save_every * float(dt):.6g} s), node {node}"

    sol = _march.check_failure(sol, sol.result, where, throw)
    if force is None:  # conservative: the energy error measures the run's meaning
        warn_if_meaningless(sol.energy, "time_march")
    return sol


def _start(system, g0, xi0, g1, dt, ds, *, boundary, force, tau, rtol, max_iterations):
    """The engine and the carry at row 0 (p⁰ from the continuous or the discrete Legendre map)."""
    w_free = _march.free_strain(system, "time", g0.dtype, rtol)
    node_force = None
    if force is not None:

        def node_force(k, g):
            s = ds * jnp.arange(g.shape[0], dtype=g.dtype)
            return jax.vmap(lambda s_a, g_a: force(k * dt, s_a, g_a))(s, g)

    engine = _march.Engine(
        system, tau, "time", dt, ds, w_free, boundary == "clamped-free", node_force, rtol, max_iterations
    )
    k0 = jnp.zeros((), jnp.int32)
    if xi0 is not None:
        p0 = jax.vmap(lambda x: jax.grad(system.lagrangian)(x, jnp.zeros_like(x)))(xi0)
        v0 = xi0
    else:
        p0, v0 = engine.legendre(k0, g0, g1)
    return engine, _march.Carry(g0, p0, v0, k0)


def _assemble(engine, rows, save_every):
    system, G = engine.system, engine.system.group
    dt, ds = engine.h_e, engine.h_t
    ghost = jax.vmap(lambda g: g @ engine.tau.tau(G, ds * engine.w_free))(rows.g[:, -1])
    energy = jax.vmap(jax.vmap(lambda x, e: time_energy_density(system, x, e)))(rows.v, rows.w)
    n_rows, nodes = rows.v.shape[:2]
    return TimeMarch(
        t=dt * save_every * jnp.arange(n_rows, dtype=dt.dtype),
        s=ds * jnp.arange(nodes + 1, dtype=dt.dtype),
        g=jnp.concatenate([rows.g, ghost[:, None]], axis=1),
        xi=rows.v,
        eta=rows.w,
        mu=rows.m,
        lam=rows.n,
        p=rows.p,
        momentum=spatial_sum(G, rows.g, rows.m, ds),
        energy=ds * jnp.sum(energy, axis=1),
        newton_iterations=rows.iterations,
        newton_residual=rows.residual,
        result=rows.result,
    )


_start_jit = single_trajectory_jit(_start)
_assemble_jit = single_trajectory_jit(_assemble)


@single_trajectory_jit
def _time_march_loop(system, g0, xi0, g1, dt, ds, n_rows, save_every, *, capacity, **options):
    engine, carry = _start(system, g0, xi0, g1, dt, ds, **options)
    return _assemble(engine, _march.advance_loop(engine, carry, n_rows, save_every, capacity), save_every)


@eqx.filter_jit
def _time_march_jit(system, g0, xi0, g1, dt, ds, *, n_steps, save_every, **options):
    engine, carry = _start(system, g0, xi0, g1, dt, ds, **options)
    return _assemble(engine, _march.run(engine, carry, n_steps, save_every), save_every)
