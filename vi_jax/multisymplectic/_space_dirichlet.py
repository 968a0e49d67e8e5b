"""The space march with Dirichlet rows (seed 003 Prop. 3.11, case (A) of §3.2; spec §4 table).

With the configuration prescribed at the time boundary, rows j = 0 and j = N, the space
evolution map (𝛗_{a−1}, 𝛗_a) ↦ (𝛗_a, 𝛗_{a+1}) of 𝖭_d lives on M₀^{N+1} (rows 0 and N fixed)
and is the DCEL (82) at the inner rows j = 1..N−1 only:

    λ_a^j = Ad*_{τ(Δsη_{a−1}^j)} λ_{a−1}^j − (Δs/Δt)[μ_a^j − Ad*_{τ(Δtξ_a^{j−1})} μ_a^{j−1}],

one dim-r Newton solve for η_a^j per inner row, g_{a+1}^j = g_a^j τ(Δs η_a^j); g_{a+1}^0 and
g_{a+1}^N are data. Column a is complete (rows 0..N), so μ_a^{N−1} comes from the data row N: no
ghost row and no zero-momentum conditions (70), unlike :func:`space_march` (Prop. 3.10 setting).
A field time-marched with zero traction (Prop. 3.11) is a solution, hence reproduced.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from .. import _validation as val
from ..lie import difference_map
from . import _march
from ._lagrangian import dual_Ad
from ._time import default_rtol, validate_rows, validate_system


class DirichletSpaceMarch(eqx.Module):
    """A field space-marched between Dirichlet rows, indexed (time row j = 0..N, column a).

    ``g`` (N+1, A, d, d); per inner row j = 1..N−1 and column a < A−1: ``eta`` η_a^j and ``lam``
    λ_a^j (solved; shape (N−1, A−1, r)). Newton statistics per (inner row, column); the solve at
    column a makes column a + 1. ``result`` 0 = success.
    """

    g: jax.Array
    eta: jax.Array
    lam: jax.Array
    newton_iterations: jax.Array
    newton_residual: jax.Array
    result: jax.Array

    @property
    def succeeded(self):
        return jnp.all(self.result == 0)


def space_march_dirichlet(
    system,
    g_col0,
    g_col1,
    g_row_first,
    g_row_last,
    *,
    dt,
    ds,
    tau="cayley",
    throw: bool = True,
    rtol=None,
    max_newton_iterations: int = 20,
) -> DirichletSpaceMarch:
    """March the DCEL (82) in space between the Dirichlet rows j = 0 and j = N (Prop. 3.11).

    ``g_col0``, ``g_col1`` (N+1, d, d): columns a = 0, 1 at t_j = jΔt, j = 0..N (N ≥ 2).
    ``g_row_first``, ``g_row_last`` (A, d, d): rows 0 and N at s_a = aΔs, a = 0..A−1 (A ≥ 2; their
    first two entries are those of the columns). Returns the A columns. Jittable, vmappable and
    differentiable (implicit-function tangents). The sideways problem amplifies errors (spec §3,
    problem 3): use float64.
    """
    G = validate_system(system)
    g_col0 = validate_rows("g_col0", G, g_col0)
    n_rows = g_col0.shape[0]
    if n_rows < 3:
        raise ValueError(f"g_col0: expected ≥ 3 rows (rows 0 and N are Dirichlet data), got {n_rows}")
    g_col1 = validate_rows("g_col1", G, g_col1, n_rows)
    g_row_first = validate_rows("g_row_first", G, g_row_first)
    n_columns = g_row_first.shape[0]
    if n_columns < 2:
        raise ValueError(f"g_row_first: expected ≥ 2 columns, got {n_columns}")
    g_row_last = validate_rows("g_row_last", G, g_row_last, n_columns)
    corners = [(g_row_first[i], col[0]) for i, col in enumerate((g_col0, g_col1))]
    corners += [(g_row_last[i], col[-1]) for i, col in enumerate((g_col0, g_col1))]
    if val.is_concrete(corners) and not all(bool(jnp.allclose(a, b, rtol=0, atol=1e-12)) for a, b in corners):
        raise ValueError("g_row_first, g_row_last: their first two entries must be the columns' rows 0 and N")
    dt = val.check_positive_scalar("dt", dt)
    ds = val.check_positive_scalar("ds", ds)
    dtype = jnp.result_type(g_col0, g_col1, g_row_first, g_row_last, dt, ds)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    arrays = (g_col0, g_col1, g_row_first, g_row_last, dt, ds)
    sol = _space_march_dirichlet_jit(
        _march.cast_system(system, dtype), *(jnp.asarray(x, dtype) for x in arrays),
        tau=difference_map(tau),
        rtol=default_rtol(dtype) if rtol is None else float(rtol), max_iterations=int(max_newton_iterations),
    )

    def where(column, row):
        j = row + 1  # the inner rows
        return f"column {column} (s ≈ {column * float(ds):.6g}), time row {j} (t ≈ {j * float(dt):.6g})"

    return _march.check_failure(sol, sol.result.T, where, throw)


@eqx.filter_jit
def _space_march_dirichlet_jit(system, g_col0, g_col1, g_row_first, g_row_last, dt, ds, *, tau, rtol, max_iterations):
    G = system.group
    # evolution along s (step Δs, velocity η, momentum λ), transverse nodes = the rows (step Δt).
    # Engine.target's entries at rows 0 and N (its free transverse boundary) and q there are unused.
    w_free = jnp.zeros(G.dim, g_col0.dtype)
    engine = _march.Engine(system, tau, "space", ds, dt, w_free, False, None, rtol, max_iterations)
    k0 = jnp.zeros((), jnp.int32)
    q0, eta0 = engine.legendre(k0, g_col0, g_col1)  # inner rows: the incoming Ad*λ_{−1} reproducing column 1
    inner = slice(1, -1)

    def column(carry, boundary):
        g, q, eta_guess, k = carry
        c, _, _ = engine.target(k, g, q)
        eta, (iterations, residual, result) = engine.solve(c[inner], eta_guess)
        lam = jax.vmap(engine.evolution_momentum)(eta)
        step = jax.vmap(lambda x: tau.tau(G, ds * x))(eta)
        g_next = jnp.concatenate([boundary[0][None], g[inner] @ step, boundary[1][None]])
        q_next = q.at[inner].set(jax.vmap(lambda s, m: dual_Ad(G, s, m))(step, lam))
        return (g_next, q_next, eta, k + 1), (g_next, eta, lam, iterations, residual, result)

    boundaries = (g_row_first[1:], g_row_last[1:])
    _, (g, eta, lam, iterations, residual, result) = jax.lax.scan(
        column, (g_col0, q0, eta0[inner], k0), jnp.stack(boundaries, axis=1)
    )
    T = lambda x: jnp.swapaxes(x, 0, 1)  # noqa: E731  (column, row) → (row, column)
    return DirichletSpaceMarch(
        g=T(jnp.concatenate([g_col0[None], g])),
        eta=T(eta),
        lam=T(lam),
        newton_iterations=T(iterations),
        newton_residual=T(residual),
        result=T(result),
    )
