"""The space march (seed 003 §5 "space evolution"; spec §3, reading B): the time trajectories
of columns 0 and 1 are data, and each spatial step solves the DCEL (82) for η_a^j, one dim-r
Newton per time row, then g_{a+1}^j = g_a^j τ(Δs η_a^j).

Rows j = 0..N−1 carry the data (T at row N−1); the ghost row g^N = g^{N−1}τ(Δt ξ_free) with
∂ℓ/∂ξ(ξ_free) = 0 (= g^{N−1} for the beam) makes μ^{N−1} = 0: the zero-momentum conditions (70)
are μ^{−1} := 0 at row 0 and μ^{N−1} := 0 at the last row (the paper's listing).
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from .. import _validation as val
from .._precision import full_precision
from ..lie import difference_map
from . import _march
from ._noether import space_energy_density, spatial_sum
from ._time import default_rtol, validate_rows, validate_system


class SpaceMarch(eqx.Module):
    """A space-marched field, indexed (time row j, column a) like a time-marched one.

    ``g`` (N+1, A, d, d) with the ghost row N; per row j < N and column a: ``eta`` η_a^j,
    ``lam`` λ_a^j, ``xi`` ξ_a^j (row N−1: ξ_free), ``mu`` μ_a^j (row N−1: 0), ``q`` the incoming
    Ad*_{τ(Δsη_{a−1}^j)}λ_{a−1}^j (the state of the space map; column 0: the discrete Legendre
    transform of the data). ``momentum`` 𝖩_𝖭(a) = Σ_j Δt Ad*_{(g_a^j)⁻¹}λ_a^j (§5) and
    ``energy`` E_N(a) = Σ_j Δt(⟨ℓ_η, η⟩ − ℓ) (spec §3) per column. Newton statistics per
    (row, column); the solve at column a makes column a + 1.
    """

    t: jax.Array
    s: jax.Array
    g: jax.Array
    xi: jax.Array
    eta: jax.Array
    mu: jax.Array
    lam: jax.Array
    q: jax.Array
    momentum: jax.Array
    energy: jax.Array
    newton_iterations: jax.Array
    newton_residual: jax.Array
    result: jax.Array

    @property
    def succeeded(self):
        return jnp.all(self.result == 0)

    @property
    def valid_columns(self) -> int:
        """Columns 0..valid_columns−1 were made by converged solves (outside ``jit``)."""
        ok = jnp.all(self.result == 0, axis=0)
        return int(jnp.argmin(ok)) + 1 if not bool(jnp.all(ok)) else int(self.g.shape[1])


def space_march(
    system,
    g_col0,
    g_col1,
    *,
    dt,
    ds,
    n_columns: int,
    tau="cayley",
    throw: bool = True,
    rtol=None,
    max_newton_iterations: int = 20,
) -> SpaceMarch:
    """March the DCEL (82) with the zero-momentum conditions (70) in space from two data columns.

    ``g_col0``, ``g_col1`` (N, d, d): g_0^j and g_1^j at t_j = jΔt, j = 0..N−1. Returns
    ``n_columns`` ≥ 2 columns (s_a = aΔs). The sideways problem amplifies errors (spec §3,
    problem 3): use float64. ``throw=False`` warns at the first failed solve and keeps the
    result codes (see :attr:`SpaceMarch.valid_columns`).
    """
    G = validate_system(system)
    g_col0 = validate_rows("g_col0", G, g_col0)
    g_col1 = validate_rows("g_col1", G, g_col1, g_col0.shape[0])
    dt = val.check_positive_scalar("dt", dt)
    ds = val.check_positive_scalar("ds", ds)
    n_columns = val.check_int("n_columns", n_columns, 2)
    dtype = jnp.result_type(g_col0, g_col1, dt, ds)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    with full_precision():
        sol = _space_march_jit(
            _march.cast_system(system, dtype), *(jnp.asarray(x, dtype) for x in (g_col0, g_col1, dt, ds)),
            n_columns=n_columns, tau=difference_map(tau),
            rtol=default_rtol(dtype) if rtol is None else float(rtol), max_iterations=int(max_newton_iterations),
        )

    def where(column, row):
        return f"column {column} (s ≈ {column * float(ds):.6g}), time row {row} (t ≈ {row * float(dt):.6g})"

    return _march.check_failure(sol, sol.result.T, where, throw)


@eqx.filter_jit
def _space_march_jit(system, g_col0, g_col1, dt, ds, *, n_columns, tau, rtol, max_iterations):
    G = system.group
    xi_free = _march.free_strain(system, "space", g_col0.dtype, rtol)
    engine = _march.Engine(system, tau, "space", ds, dt, xi_free, False, None, rtol, max_iterations)
    k0 = jnp.zeros((), jnp.int32)
    q0, eta0 = engine.legendre(k0, g_col0, g_col1)
    rows = _march.run(engine, _march.Carry(g_col0, q0, eta0, k0), n_columns - 1, 1)
    ghost = jax.vmap(lambda g: g @ tau.tau(G, dt * xi_free))(rows.g[:, -1])
    g = jnp.concatenate([rows.g, ghost[:, None]], axis=1)
    energy = jax.vmap(jax.vmap(lambda e, x: space_energy_density(system, x, e)))(rows.v, rows.w)
    T = lambda x: jnp.swapaxes(x, 0, 1)  # noqa: E731  (column, row) → (row, column)
    return SpaceMarch(
        t=dt * jnp.arange(g.shape[1], dtype=dt.dtype),
        s=ds * jnp.arange(n_columns, dtype=dt.dtype),
        g=T(g),
        xi=T(rows.w),
        eta=T(rows.v),
        mu=T(rows.n),
        lam=T(rows.m),
        q=T(rows.p),
        momentum=spatial_sum(G, rows.g, rows.m, dt),
        energy=dt * jnp.sum(energy, axis=1),
        newton_iterations=T(rows.iterations),
        newton_residual=T(rows.residual),
        result=T(rows.result),
    )
