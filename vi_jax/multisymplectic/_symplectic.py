"""Checks of the geometry with ``jax.jvp`` first variations (seed 003 §§3.2–3.3, 4.2; spec §4).

Variations are left-trivialised, ζ = g⁻¹δg. On T*Gⁿ ≅ Gⁿ × (g*)ⁿ (left trivialisation) the
canonical form is ω(V, W) = Σ_i ⟨δ_W p_i, ζ_V,i⟩ − ⟨δ_V p_i, ζ_W,i⟩ + ⟨p_i, [ζ_V,i, ζ_W,i]⟩;
the time map (g^j, Δs p^j) ↦ (g^{j+1}, Δs p^{j+1}) and the space map (g_a, Δt q_a) ↦
(g_{a+1}, Δt q_{a+1}) preserve it (Props 3.6–3.12). The Cartan forms Ω^k = −dΘ^k with
Θ^k = ⟨P^k, ζ⁽ᵏ⁾⟩ (eqs. 30, 72) give the multisymplectic form formula (33).
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from ._lagrangian import field_function, triangle_vertex_momenta
from ._space import space_march
from ._time import time_march


def _trivialise(group, g, dg):
    return jnp.vectorize(lambda a, b: group.vee(group.inverse(a) @ b), signature="(d,d),(d,d)->(r)")(g, dg)


def _right_perturbation(group, g, zeta):
    """δg = g ζ̂ for a left-trivialised variation ζ."""
    return jnp.vectorize(lambda a, z: a @ group.hat(z), signature="(d,d),(r)->(d,d)")(g, zeta)


def _pairing_terms(group, p, zeta_V, dp_V, zeta_W, dp_W):
    bracket = jnp.vectorize(group.bracket, signature="(r),(r)->(r)")(zeta_V, zeta_W)
    return (
        jnp.sum(dp_W * zeta_V, -1),
        -jnp.sum(dp_V * zeta_W, -1),
        jnp.sum(p * bracket, -1),
    )


@eqx.filter_jit
def symplectic_form(group, g, p, dg_V, dp_V, dg_W, dp_W):
    """ω(V, W) on T*Gⁿ for states (g (…, n, d, d), p (…, n, r)) and tangents (δg, δp);
    returns (ω, Σ|terms|) summed over the node axis."""
    terms = _pairing_terms(group, p, _trivialise(group, g, dg_V), dp_V, _trivialise(group, g, dg_W), dp_W)
    return sum(jnp.sum(t, -1) for t in terms), sum(jnp.sum(jnp.abs(t), -1) for t in terms)


def time_march_jvp(system, g0, xi0, V, *, d_system=None, **march_options):
    """A time march and its first variation along V = (ζ₀ (A, r), δξ₀ (A, r)), the left-trivialised
    variation of g0 and the variation of xi0, and along ``d_system`` (a tangent of the system's
    floating-point parameters; default zero): (TimeMarch, its tangent) by forward mode."""
    march = lambda sys, g, xi: time_march(sys, g, xi0=xi, **march_options)  # noqa: E731
    dynamic = eqx.filter(system, eqx.is_inexact_array)
    d_system = jax.tree.map(jnp.zeros_like, dynamic) if d_system is None else d_system
    tangents = (d_system, _right_perturbation(system.group, g0, V[0]), V[1])
    return eqx.filter_jvp(march, (system, g0, xi0), tangents)


def space_march_jvp(system, g_col0, g_col1, V, **march_options):
    """A space march and its first variation along V = (ζ of column 0 (N, r), ζ of column 1):
    (SpaceMarch, its tangent) by ``jax.jvp``."""
    G = system.group
    march = lambda c0, c1: space_march(system, c0, c1, **march_options)  # noqa: E731
    tangents = (_right_perturbation(G, g_col0, V[0]), _right_perturbation(G, g_col1, V[1]))
    return jax.jvp(march, (g_col0, g_col1), tangents)


def time_map_symplecticity(system, g0, xi0, V, W, **march_options):
    """ω along a time march (see :func:`time_march`) for two first variations V, W of the initial
    data (as in :func:`time_march_jvp`): (ω per saved row, Σ|terms| per row). The state of the
    time map is (g^j, Δs p^j) on the massive nodes; ω is constant if the map is symplectic."""
    ds = march_options["ds"]
    sol, dV = time_march_jvp(system, g0, xi0, V, **march_options)
    _, dW = time_march_jvp(system, g0, xi0, W, **march_options)
    massive = lambda x: x.g[:, :-1]  # noqa: E731
    return symplectic_form(system.group, massive(sol), ds * sol.p, massive(dV), ds * dV.p, massive(dW), ds * dW.p)


def space_map_symplecticity(system, g_col0, g_col1, V, W, **march_options):
    """ω along a space march (see :func:`space_march`) for two first variations V, W of the data
    columns (as in :func:`space_march_jvp`): (ω per column, Σ|terms| per column). The state of
    the space map at column a is (g_a^j, Δt q_a^j), j = 0..N−1."""
    dt = march_options["dt"]
    sol, dV = space_march_jvp(system, g_col0, g_col1, V, **march_options)
    _, dW = space_march_jvp(system, g_col0, g_col1, W, **march_options)
    columns = lambda x: jnp.swapaxes(x.g[:-1], 0, 1)  # noqa: E731
    q = lambda x: dt * jnp.swapaxes(x.q, 0, 1)  # noqa: E731
    return symplectic_form(system.group, columns(sol), q(sol), columns(dV), q(dV), columns(dW), q(dW))


@eqx.filter_jit
def field_variation(group, g, dg):
    """ζ = g⁻¹δg at every node of a field variation (e.g. the tangent of a march)."""
    return _trivialise(group, g, dg)


@field_function
def multisymplectic_formula(system, g, zeta_V, zeta_W, rows, cols, *, dt, ds, tau="cayley"):
    """The discrete multisymplectic form formula (33) on the rectangle of triangles
    K ≤ j ≤ L, B ≤ a ≤ C (``rows = (K, L)``, ``cols = (B, C)``, traced: one compilation serves
    every rectangle):

        Σ_{△ in the rectangle} Σ_{k: vertex k not inside} Ω^k(V, W),
        Ω^k(V, W) = ⟨δ_W P^k, ζ_V⁽ᵏ⁾⟩ − ⟨δ_V P^k, ζ_W⁽ᵏ⁾⟩ + ⟨P^k, [ζ_V⁽ᵏ⁾, ζ_W⁽ᵏ⁾]⟩,

    for first variations ζ_V, ζ_W (rows, cols, r) of a field g that solves the DCEL at the
    rectangle's inner nodes (K < j ≤ L, B < a ≤ C). Returns (value, Σ|terms|); value ≈ 0.
    """
    G = system.group
    (K, L), (B, C) = jnp.asarray(rows), jnp.asarray(cols)

    def omega(g1, g2, g3, zV, zW):
        gs = (g1, g2, g3)
        P = lambda *h: triangle_vertex_momenta(system, tau, dt, ds, *h)  # noqa: E731
        tV, tW = ([_right_perturbation(G, x, z) for x, z in zip(gs, zs)] for zs in (zV, zW))
        Ps, dP_V = jax.jvp(P, gs, tuple(tV))
        _, dP_W = jax.jvp(P, gs, tuple(tW))
        return jnp.stack(
            [jnp.stack(_pairing_terms(G, Ps[k], zV[k], dP_V[k], zW[k], dP_W[k])) for k in range(3)]
        )  # (vertex k, term)

    vertices = lambda x: (x[:-1, :-1], x[1:, :-1], x[:-1, 1:])  # noqa: E731
    stack3 = lambda x: jnp.stack(vertices(x), axis=2)  # noqa: E731  (rows, cols, 3, r)
    terms = jax.vmap(jax.vmap(omega))(*vertices(g), stack3(zeta_V), stack3(zeta_W))  # (rows, cols, 3, 3)
    j = jnp.arange(g.shape[0])[:, None]
    a = jnp.arange(g.shape[1])[None, :]
    inner = (j >= K + 1) & (j <= L) & (a >= B + 1) & (a <= C)
    in_rectangle = ((j >= K) & (j <= L) & (a >= B) & (a <= C))[:-1, :-1]
    on_boundary = ~jnp.stack(vertices(inner), axis=2) & in_rectangle[..., None]  # (rows − 1, cols − 1, 3)
    mask = on_boundary[..., None].astype(terms.dtype)
    return jnp.sum(terms * mask), jnp.sum(jnp.abs(terms) * mask)
