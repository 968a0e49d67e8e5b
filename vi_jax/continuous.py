"""The continuous Euler–Poincaré equations with advected parameters and additional dynamics
(seed 000 eqs. 12–13, 20–21), built by autodiff from the same reduced Lagrangian a scene has,
with the reconstruction equations, as a diffrax ``ODETerm``.

State y = (g, ξ, q, ν) (q, ν are None without additional dynamics). With μ = ℓ_ξ, p = ℓ_ν:

  μ̇ = ad*_ξ μ + ℓ_a◇a + ℓ_n◇n + ℓ_ν◇ν,   ṗ = ℓ_n + ρ'_Q(ξ)ᵀp,
  ṅ = ν − ρ'_Q(ξ)n,   ȧ = −ρ'_V(ξ)a,   ġ = gξ̂,   q̇ = ρ_Q(g)ν,

solved for (ξ̇, ν̇) in velocity form: H·[ξ̇; ν̇] = [μ̇; ṗ] − (∂_n∇ℓ)ṅ − (∂_a∇ℓ)ȧ with H the Hessian
of ℓ in (ξ, ν) (ℓ must be regular). The energy and Kelvin–Noether quantity (eqs. 27–28) are
the same functions the discrete solutions report.

Cost: what is constant along solutions is found once, when the field is built, from the jaxprs
of ℓ's derivatives (so for any parameter values, traced ones included): a constant H is inverted
once, and with momenta independent of (n, a) the Lagrangian is exactly ℓ(0, n, 0, a) + cᵀz + ½zᵀHz
(z = (ξ, ν)), so the momenta are Hz + c and only the forces need autodiff per call. The
bilinear maps (ad*, ◇, ρ', gξ̂) are applied from their nonzero coefficients, read off once.
``python benchmarks/vector_field.py`` times the field against hand-written ones.
"""

import functools
import operator

import diffrax
import equinox as eqx
import jax
import jax.extend.core as jex
import jax.numpy as jnp
import numpy as np

from ._diagnostics import kelvin_noether as _kelvin_noether, kelvin_noether_scale as _kelvin_noether_scale
from .solvers import dense_solve
from ._system import AbstractSystem, State


def _reduced(system, g, q):
    return system.body_configuration(g, q), system.body_advected(g)


def _velocities(system, xi, nu):
    return xi if nu is None else jnp.concatenate([xi, nu])


def _momenta_flat(system, z, n, a):
    r = system.group.dim
    xi, nu = (z[:r], z[r:]) if system.has_additional else (z, None)
    mu, p = system.momenta(xi, n, nu, a)
    return mu if p is None else jnp.concatenate([mu, p])


def _hessian(system, z, n, a):
    """H = ∂(ℓ_ξ, ℓ_ν)/∂(ξ, ν)."""
    return jax.jacfwd(_momenta_flat, argnums=1)(system, z, n, a)


def _sample_point(system):
    """(ξ, n, ν, a) = (0, 0, 0, a₀): where the constants are evaluated (anywhere would do)."""
    G = system.group
    eye = G.identity(jnp.zeros(()).dtype)
    xi = jnp.zeros(G.dim, eye.dtype)
    nu = n = None
    if system.has_additional:
        nu = n = jnp.zeros(jax.eval_shape(system.configuration_action.matrix, eye).shape[-1], eye.dtype)
    return xi, n, nu, system.body_advected(eye)


@eqx.filter_jit
def _constants(system):
    """H, H⁻¹ and c = ∇_z ℓ at z = 0, for an H that depends on nothing of the state. H⁻¹ by the
    same elimination as the per-call solve (``dense_solve``): fused elementwise code rather than
    LAPACK calls, which add a fixed cost (tens of µs) to every solve."""
    xi, n, nu, a = _sample_point(system)
    z = _velocities(system, xi, nu)
    H = _hessian(system, z, n, a)
    return H, dense_solve(H, jnp.eye(H.shape[0], dtype=H.dtype)), _momenta_flat(system, z, n, a)


def _columns(A, x):
    """A x as Σ_j A[:, j] x_j: fused with what produces x, each x_j is computed once (a reduction
    recomputes it for every output entry)."""
    return functools.reduce(operator.add, [A[:, j] * x[j] for j in range(x.shape[0])])


# ----------------------------------------------------------------------- structure, found once

_CALLS = {"pjit", "jit", "closed_call", "core_call", "custom_jvp_call", "custom_vjp_call", "checkpoint", "remat"}


def _used_inputs(jaxpr, used_outputs):
    """Which inputs of ``jaxpr`` the used outputs depend on: a backward pass that enters calls
    (jit, custom derivatives, remat) and counts every input of any other primitive."""
    used = {v for v, u in zip(jaxpr.outvars, used_outputs) if u and not isinstance(v, jex.Literal)}
    for eqn in reversed(jaxpr.eqns):
        outs = [v in used for v in eqn.outvars]
        if not any(outs):
            continue
        inner = list(jex.jaxprs_in_params(eqn.params))
        if eqn.primitive.name in _CALLS and len(inner) == 1 and len(inner[0].invars) == len(eqn.invars):
            ins = _used_inputs(inner[0], outs)
        else:
            ins = [True] * len(eqn.invars)
        used.update(v for v, u in zip(eqn.invars, ins) if u and not isinstance(v, jex.Literal))
    return [v in used for v in jaxpr.invars]


def _dependence(fn, system, *args):
    """D[o][k]: whether output leaf o of ``fn(system, *args)`` depends on ``args[k]`` (shapes),
    from the jaxpr (exact for any values of the system's parameters)."""
    params, static = eqx.partition(system, eqx.is_array)
    spec = lambda x: jax.ShapeDtypeStruct(jnp.shape(x), jnp.result_type(x))  # noqa: E731
    closed = jax.make_jaxpr(lambda p, *xs: fn(eqx.combine(p, static), *xs))(jax.tree.map(spec, params), *args)
    sizes = [len(jax.tree.leaves(x)) for x in (params, *args)]
    starts = np.cumsum([0] + sizes)
    rows = []
    for o in range(len(closed.jaxpr.outvars)):
        used = _used_inputs(closed.jaxpr, [k == o for k in range(len(closed.jaxpr.outvars))])
        rows.append([any(used[starts[k + 1] : starts[k + 2]]) for k in range(len(args))])
    return rows


def _terms(T):
    """Per flat output entry o, the nonzero terms (c, i, j) of f(u, v)_o = Σ c u_i v_j, from
    T[i, j] = f(e_i, e_j) of shape (u, v, output); with the output shape."""
    T = np.asarray(T)
    out_shape = tuple(int(k) for k in T.shape[2:])
    T = np.moveaxis(T.reshape(T.shape[0], T.shape[1], -1), -1, 0)
    return out_shape, tuple(tuple((float(T[o, i, j]), int(i), int(j)) for i, j in zip(*np.nonzero(T[o]))) for o in range(len(T)))


def _bilinear_maps(G, V, Q):
    """The bilinear maps of the equations by name: (f, shapes of u and v)."""
    r, d = G.dim, G.matrix_size
    maps = {"ad_dual": (G.ad_dual, (r,), (r,)), "reconstruct": (lambda g, xi: G.compose(g, G.hat(xi)), (d, d), (r,))}
    for key, action in (("V", V), ("Q", Q)):
        if action is not None:
            m = jax.eval_shape(action.matrix, jax.ShapeDtypeStruct((d, d), jnp.zeros(()).dtype)).shape[-1]
            maps[key + "_diamond"] = (action.diamond, (m,), (m,))
            maps[key + "_infinitesimal"] = (action.infinitesimal, (r,), (m,))
            if key == "Q":
                maps["Q_infinitesimal_transpose"] = (action.infinitesimal_transpose, (r,), (m,))
    return maps


def _bilinear_tables(G, V, Q, dtype):
    """Coefficient tables (``_terms``) of the bilinear maps, from their values on pairs of basis
    vectors (of ``dtype``) in one compiled call at trace time; () if they involve traced values
    (the maps then run as written)."""
    maps = _bilinear_maps(G, V, Q)

    def on_basis(bases):  # the bases are arguments: traced, so compiled once
        return {k: jax.vmap(lambda e, f=maps[k][0], E=E: jax.vmap(lambda e2: f(e, e2))(E))(U) for k, (U, E) in bases.items()}

    def basis(shape):
        size = int(np.prod(shape))
        return jnp.eye(size, dtype=dtype).reshape((size, *shape))

    with jax.ensure_compile_time_eval():
        T = jax.jit(on_basis)({k: (basis(u), basis(v)) for k, (_, u, v) in maps.items()})
    if any(isinstance(t, jax.core.Tracer) for t in T.values()):
        return ()
    return tuple((k, _terms(T[k])) for k in maps)


_cached_bilinear_tables = functools.lru_cache(maxsize=64)(_bilinear_tables)


def _stack(entries, shape):
    """Scalars into an array of ``shape`` by stacks of at most 8 operands: XLA:CPU fuses none
    of a wider concatenation's operands (each becomes a kernel of its own)."""
    if len(shape) > 1:
        size = len(entries) // shape[0]
        return jnp.stack([_stack(entries[k * size : (k + 1) * size], shape[1:]) for k in range(shape[0])])
    parts = [jnp.stack(entries[k : k + 8]) for k in range(0, len(entries), 8)]
    while len(parts) > 1:
        parts = [jnp.concatenate(parts[k : k + 8]) for k in range(0, len(parts), 8)]
    return parts[0]


def _apply_bilinear(terms, u, v):
    """f(u, v) from its table, one scalar sum of products per output entry."""
    out_shape, rows = terms
    u, v = u.reshape(-1), v.reshape(-1)
    entries = []
    for row in rows:
        acc = None
        for c, i, j in row:
            t = u[i] * v[j]
            if acc is None:
                acc = t if c == 1 else (-t if c == -1 else c * t)
            else:
                acc = acc + t if c == 1 else (acc - t if c == -1 else acc + c * t)
        entries.append(jnp.zeros((), jnp.result_type(u, v)) if acc is None else acc)
    return _stack(entries, out_shape)


class EulerPoincareField(eqx.Module):
    """dy/dt for y = (g, ξ, q, ν), with what is constant along solutions computed once.

    ``hessian``/``inverse_hessian``: H and H⁻¹ when H depends on nothing of the state (else
    None: H is built and solved per call); ``separable``: H constant and (ℓ_ξ, ℓ_ν) independent
    of (n, a), so ∇_z ℓ = Hz + ``momentum_offset`` exactly and the drift term vanishes;
    ``block_diagonal``: ℓ_ξ independent of ν and ℓ_ν of ξ; ``bilinear``: coefficient tables of
    the bilinear maps (``_bilinear_tables``), applied entry by entry (``_apply_bilinear``).
    """

    system: AbstractSystem
    hessian: jax.Array | None
    inverse_hessian: jax.Array | None
    momentum_offset: jax.Array | None
    separable: bool = eqx.field(static=True)
    drift: bool = eqx.field(static=True)
    block_diagonal: bool = eqx.field(static=True)
    bilinear: tuple = eqx.field(static=True)

    def __init__(self, system: AbstractSystem):
        self.system = system
        xi, n, nu, a = jax.eval_shape(_sample_point, system)
        z = jax.ShapeDtypeStruct((xi.shape[0] + (0 if nu is None else nu.shape[0]),), xi.dtype)
        (hessian_dependence,) = _dependence(_hessian, system, z, n, a)
        momenta_dependence = _dependence(lambda s, *args: s.momenta(*args), system, xi, n, nu, a)
        self.drift = any(row[1] or row[3] for row in momenta_dependence)
        self.block_diagonal = system.has_additional and not (momenta_dependence[0][2] or momenta_dependence[1][0])
        constant = not any(hessian_dependence)
        self.separable = constant and not self.drift
        H, H_inv, c = _constants(system) if constant else (None, None, None)
        self.hessian, self.inverse_hessian = H, H_inv
        self.momentum_offset = c if self.separable else None
        owners = (system.group, system.advected_action, system.configuration_action, jnp.zeros(()).dtype)
        try:  # cached per group and actions: a field is built at every trace
            self.bilinear = _cached_bilinear_tables(*owners)
        except TypeError:  # unhashable
            self.bilinear = _bilinear_tables(*owners)

    def _body(self, g, q):
        """n = ρ_Q(g)⁻¹q and a = ρ_V(g)⁻¹a₀ (``AbstractSystem.body_*``), a from the nonzero
        entries of the concrete a₀ only."""
        system, G = self.system, self.system.group
        n = a = None
        if system.has_additional:
            n = _columns(system.configuration_action.matrix(G.inverse(g)), q)
        if system.has_advected:
            a0 = np.asarray(system.advected_reference).reshape(-1)
            A = system.advected_action.matrix(G.inverse(g))
            terms = [A[:, j] if a0[j] == 1 else float(a0[j]) * A[:, j] for j in np.flatnonzero(a0)]
            a = functools.reduce(operator.add, terms) if terms else jnp.zeros(A.shape[0], g.dtype)
        return n, a

    def _bilinear(self, name, f, u, v):
        terms = dict(self.bilinear).get(name)
        return f(u, v) if terms is None else _apply_bilinear(terms, u, v)

    def _product(self, A, parts):
        """A·(ξ, ν) for A = H or H⁻¹ (cast to the parts' dtype), as parts; blockwise when H is
        block diagonal."""
        A = A.astype(parts[0].dtype)
        if len(parts) == 1:
            return [_columns(A, parts[0])]
        r = self.system.group.dim
        if self.block_diagonal:
            return [_columns(A[:r, :r], parts[0]), _columns(A[r:, r:], parts[1])]
        out = _columns(A, jnp.concatenate(parts))
        return [out[:r], out[r:]]

    def _derivatives(self, xi, n, nu, a):
        """(ℓ_ξ, ℓ_n, ℓ_ν, ℓ_a)."""
        lagrangian = self.system.lagrangian
        if not self.separable:
            return jax.grad(lagrangian, argnums=(0, 1, 2, 3))(xi, n, nu, a)
        parts = [xi] if nu is None else [xi, nu]
        r = self.system.group.dim
        offset = self.momentum_offset.astype(xi.dtype)
        momenta = [m + c for m, c in zip(self._product(self.hessian, parts), (offset[:r], offset[r:]))]
        zeros = lambda x: None if x is None else jnp.zeros_like(x)  # noqa: E731
        ell_n, ell_a = jax.grad(lambda n_, a_: lagrangian(zeros(xi), n_, zeros(nu), a_), argnums=(0, 1))(n, a)
        return momenta[0], ell_n, (None if nu is None else momenta[1]), ell_a

    def __call__(self, t, y, args=None):
        system, bil = self.system, self._bilinear
        G = system.group
        g, xi, q, nu = y
        n, a = self._body(g, q)
        ell_xi, ell_n, ell_nu, ell_a = self._derivatives(xi, n, nu, a)
        mu_dot = bil("ad_dual", G.ad_dual, xi, ell_xi)
        n_dot = a_dot = q_dot = None
        if system.has_advected:
            V = system.advected_action
            mu_dot = mu_dot + bil("V_diamond", V.diamond, ell_a, a)
            a_dot = -bil("V_infinitesimal", V.infinitesimal, xi, a)
        rates = [mu_dot]
        if system.has_additional:
            Q = system.configuration_action
            rates[0] = mu_dot + bil("Q_diamond", Q.diamond, ell_n, n) + bil("Q_diamond", Q.diamond, ell_nu, nu)
            rates.append(ell_n + bil("Q_infinitesimal_transpose", Q.infinitesimal_transpose, xi, ell_nu))
            n_dot = nu - bil("Q_infinitesimal", Q.infinitesimal, xi, n)
            q_dot = _columns(Q.matrix(g), nu)
        if self.drift:
            zeros = lambda x: None if x is None else jnp.zeros_like(x)  # noqa: E731
            z = _velocities(system, xi, nu)
            _, drift = jax.jvp(
                lambda n_, a_: _momenta_flat(system, z, n_, a_),
                (n, a),
                (zeros(n) if n_dot is None else n_dot, zeros(a) if a_dot is None else a_dot),
            )
            rates = [rates[0] - drift[: G.dim]] + [rate - drift[G.dim :] for rate in rates[1:]]
        if self.inverse_hessian is None:
            z = _velocities(system, xi, nu)
            z_dot = dense_solve(_hessian(system, z, n, a), jnp.concatenate(rates))
            velocity_rates = [z_dot[: G.dim], z_dot[G.dim :]]
        else:
            velocity_rates = self._product(self.inverse_hessian, rates)
        nu_dot = velocity_rates[1] if system.has_additional else None
        dg = bil("reconstruct", lambda g_, xi_: G.compose(g_, G.hat(xi_)), g, xi)
        return (dg, velocity_rates[0], q_dot, nu_dot)


def time_derivative(system: AbstractSystem, y):
    """dy/dt for y = (g, ξ, q, ν)."""
    return EulerPoincareField(system)(0.0, y)


def vector_field(system: AbstractSystem) -> diffrax.ODETerm:
    """The continuous EP equations as a diffrax term on y = (g, ξ, q, ν)."""
    return diffrax.ODETerm(EulerPoincareField(system))


def initial_state(system: AbstractSystem, x0: State):
    """y₀ = (g, ξ, q, ν) from the continuous initial data (ν = ρ_Q(g)⁻¹q̇ in the body frame)."""
    nu = None
    if system.has_additional:
        nu = system.configuration_action.act_inverse(x0.g, x0.qdot)
    return (x0.g, x0.xi, x0.q, nu)


def energy(system: AbstractSystem, y):
    """E = ⟨ℓ_ξ, ξ⟩ + ⟨ℓ_ν, ν⟩ − ℓ at y (works on a leading time axis too)."""
    g, xi, q, nu = y
    if g.ndim == 3:
        return jax.vmap(lambda *s: energy(system, s))(g, xi, q, nu)
    n, a = _reduced(system, g, q)
    return system.energy(xi, n, nu, a)


def kelvin_noether_scale(system: AbstractSystem, y):
    """|μ| + |p||n|: the size of the terms that cancel in the Kelvin–Noether quantity."""
    g, xi, q, nu = y
    if g.ndim == 3:
        return jax.vmap(lambda *s: kelvin_noether_scale(system, s))(g, xi, q, nu)
    n, a = _reduced(system, g, q)
    mu, p = system.momenta(xi, n, nu, a)
    return _kelvin_noether_scale(system, g, q, mu, p)


def kelvin_noether(system: AbstractSystem, y):
    """I = ⟨ζ, Ad*_{g⁻¹}(μ − p◇n)⟩ for ζ in the isotropy algebra of a₀ (eqs. 27–28)."""
    g, xi, q, nu = y
    if g.ndim == 3:
        return jax.vmap(lambda *s: kelvin_noether(system, s))(g, xi, q, nu)
    n, a = _reduced(system, g, q)
    mu, p = system.momenta(xi, n, nu, a)
    value = _kelvin_noether(system, g, q, mu, p)
    return value[0] if value.shape[-1] == 1 else value


def solve(system: AbstractSystem, x0: State, t1, *, solver=None, rtol=1e-10, atol=1e-10, saveat=None, max_steps=1_000_000, dt0=None):
    """Convenience: integrate the continuous equations with diffrax (default Dopri8 + PID)."""
    return diffrax.diffeqsolve(
        vector_field(system), solver or diffrax.Dopri8(), 0.0, t1, dt0, initial_state(system, x0),
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
        saveat=saveat or diffrax.SaveAt(t1=True), max_steps=max_steps,
    )
