"""The fast paths of ``vj.continuous.vector_field`` (constant Hessian inverted once, separable
momenta, block structure, bilinear maps from their coefficients) against the plain equations,
and the hand-written fields of ``benchmarks/hand_fields.py`` (the benchmark's peers) against
both.

Tolerances: every rate is H⁻¹ times a sum of at most a few dozen products, evaluated in another
order (and with H⁻¹ instead of a solve), so two evaluations differ by about (k + κ(H))·eps·S,
S = ‖H⁻¹‖ times the largest term (``_scale``), k ≲ 50 roundings, κ(H) ≤ 38 here (the
vehicle's M/J): ≲ 2e-14·S in float64, and 1e-12·S leaves a margin of ~50.
"""

import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import vi_jax as vj
from vi_jax import continuous
from vi_jax.lie import SO3, LinearAction, SOn

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from hand_fields import heavy_top_field, vehicle_field  # noqa: E402


def reference(system, y):
    """The equations of the module docstring written plainly: full gradients, Hessian by
    jacfwd and a dense solve per call, the actions' own methods."""
    g, xi, q, nu = y
    G, V, Q = system.group, system.advected_action, system.configuration_action
    n, a = system.body_configuration(g, q), system.body_advected(g)
    l_xi, l_n, l_nu, l_a = jax.grad(system.lagrangian, argnums=(0, 1, 2, 3))(xi, n, nu, a)
    mu_dot, n_dot, a_dot = G.ad_dual(xi, l_xi), None, None
    if V is not None:
        mu_dot, a_dot = mu_dot + V.diamond(l_a, a), -V.infinitesimal(xi, a)
    rhs = mu_dot
    if Q is not None:
        mu_dot = mu_dot + Q.diamond(l_n, n) + Q.diamond(l_nu, nu)
        rhs = jnp.concatenate([mu_dot, l_n + Q.infinitesimal_transpose(xi, l_nu)])
        n_dot = nu - Q.infinitesimal(xi, n)
    r = G.dim

    def momenta(z, n_, a_):
        mu, p = system.momenta(z[:r], n_, None if nu is None else z[r:], a_)
        return mu if p is None else jnp.concatenate([mu, p])

    z = xi if nu is None else jnp.concatenate([xi, nu])
    zero = lambda x: None if x is None else jnp.zeros_like(x)  # noqa: E731
    tangents = (zero(n) if n_dot is None else n_dot, zero(a) if a_dot is None else a_dot)
    _, drift = jax.jvp(lambda n_, a_: momenta(z, n_, a_), (n, a), tangents)
    z_dot = jnp.linalg.solve(jax.jacfwd(momenta)(z, n, a), rhs - drift)
    return g @ G.hat(xi), z_dot[:r], None if Q is None else Q.act(g, nu), None if Q is None else z_dot[r:]


def _scale(system, y):
    """Size of the largest term entering the rates: ‖H⁻¹‖ times the largest |gradient|·|state|
    product, and |g||ξ| for ġ."""
    g, xi, q, nu = y
    n, a = system.body_configuration(g, q), system.body_advected(g)
    grads = [x for x in jax.grad(system.lagrangian, argnums=(0, 1, 2, 3))(xi, n, nu, a) if x is not None]
    states = [x for x in (xi, n, nu, a) if x is not None]
    big = max(float(jnp.max(jnp.abs(x))) for x in grads) * max(1.0, max(float(jnp.max(jnp.abs(x))) for x in states))
    z = xi if nu is None else jnp.concatenate([xi, nu])
    r = system.group.dim
    split = lambda z_: (z_[:r], n, None if nu is None else z_[r:], a)  # noqa: E731
    H = jax.jacfwd(lambda z_: jnp.concatenate([m for m in system.momenta(*split(z_)) if m is not None]))(z)
    return max(1.0, big * float(jnp.max(jnp.sum(jnp.abs(jnp.linalg.inv(H)), axis=1))), float(jnp.max(jnp.abs(xi))))


def _states(system, rng, count=3):
    G, r = system.group, system.group.dim
    out = []
    for _ in range(count):
        g = G.exp(jnp.asarray(rng.normal(size=r)))
        xi = jnp.asarray(rng.normal(size=r))
        q = nu = None
        if system.has_additional:
            q, nu = jnp.asarray(10 * rng.normal(size=3)), jnp.asarray(rng.normal(size=3))
        out.append((g, xi, q, nu))
    return out


def _assert_close(ours, ref, scale):
    for a, b in zip(ours, ref):
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * scale)


J3 = np.array([[2.0, 0.3, -0.1], [0.3, 1.5, 0.2], [-0.1, 0.2, 1.0]])
M3 = np.array([[3.0, 0.2, 0.0], [0.2, 2.5, -0.3], [0.0, -0.3, 2.0]])
E_Z = np.array([0.0, 0.0, 1.0])


def _scene(kind):
    """Scenes that take each path: ``separable`` (H constant, momenta free of (n, a)), ``coupled``
    (separable, H not block diagonal), ``drift`` (H constant, momenta depend on n), ``general``
    (H depends on the state)."""
    action = LinearAction(SO3(), rho=lambda g: g)  # a user representation: ρ' by jvp
    if kind == "separable":
        return vj.System(SO3(), lambda xi, n, nu, a, p: 0.5 * xi @ J3 @ xi + 0.5 * nu @ M3 @ nu + 0.5 * xi[0] + 0.2 * nu[1] - 3.0 * n @ a + a[0],
                         advected=(action, E_Z), additional=action)  # linear terms: a momentum offset (a gyrostat)
    if kind == "coupled":
        return vj.System(SO3(), lambda xi, n, nu, a, p: 0.5 * xi @ J3 @ xi + 0.5 * nu @ M3 @ nu + 0.4 * xi @ nu - n @ a,
                         advected=(LinearAction(SO3()), E_Z), additional=LinearAction(SO3()))
    if kind == "drift":
        return vj.System(SO3(), lambda xi, n, nu, a, p: 0.5 * xi @ J3 @ xi + 0.5 * nu @ M3 @ nu + 0.7 * xi @ n - n @ a,
                         advected=(LinearAction(SO3()), E_Z), additional=LinearAction(SO3()))
    return vj.System(SO3(), lambda xi, n, nu, a, p: 0.5 * xi @ J3 @ xi + 0.1 * (xi @ xi) ** 2 + 0.3 * (xi @ a) ** 2 - 2.0 * a[2],
                     advected=(LinearAction(SO3()), E_Z))


def test_paths_equal_the_plain_equations():
    rng = np.random.default_rng(0)
    expected = {  # (separable, constant Hessian, block diagonal, drift)
        "separable": (True, True, True, False),
        "coupled": (True, True, False, False),
        "drift": (False, True, True, True),
        "general": (False, False, False, True),
    }
    scenes = {kind: _scene(kind) for kind in expected}
    scenes["vehicle"], expected["vehicle"] = vj.models.UnderwaterVehicle(), (True, True, True, False)
    scenes["heavy top SO(4)"], expected["heavy top SO(4)"] = vj.models.HeavyTop(group=SOn(4)), (True, True, False, False)
    for kind, system in scenes.items():
        field = continuous.EulerPoincareField(system)
        flags = (field.separable, field.inverse_hessian is not None, field.block_diagonal, field.drift)
        assert flags == expected[kind], kind
        ours, ref = jax.jit(lambda y, s=system: continuous.time_derivative(s, y)), jax.jit(lambda y, s=system: reference(s, y))
        for y in _states(system, rng, 2):
            _assert_close(ours(y), ref(y), _scale(system, y))


def test_structure_found_with_traced_parameters():
    """Under jit with the scene as an argument the parameters are traced: the structure is
    still found (from the jaxpr, not from values) and the field is unchanged."""
    model = vj.models.UnderwaterVehicle()
    y = _states(model, np.random.default_rng(1), 1)[0]

    def traced(system, y):
        field = continuous.EulerPoincareField(system)
        assert field.separable and field.block_diagonal and not field.drift
        return field(0.0, y)

    _assert_close(jax.jit(traced)(model, y), reference(model, y), _scale(model, y))


def test_parameter_gradient_equals_plain_equations():
    """d(field)/d(inertia) along a direction, through the inverted-once Hessian, equals that of
    the plain equations."""
    model = vj.models.UnderwaterVehicle()
    y = _states(model, np.random.default_rng(2), 1)[0]

    dJ = jnp.array([[0.3, -0.2, 0.1], [-0.2, 0.5, 0.4], [0.1, 0.4, -0.6]])

    def through(f):
        rates = lambda J: jnp.concatenate([f(eqx.tree_at(lambda m: m.inertia, model, J), y)[k] for k in (1, 3)])  # noqa: E731
        return jax.jvp(rates, (model.inertia,), (dJ,))[1]

    ours, ref = through(continuous.time_derivative), through(reference)
    # Both differentiate the same expressions: round-off of the rates times ‖∂H⁻¹/∂J‖ ≤ ‖H⁻¹‖².
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-11 * float(jnp.max(jnp.abs(ref))))


def test_hand_fields_equal_vector_field():
    """The benchmark's hand-written fields are the same equations (so timing them is fair)."""
    rng = np.random.default_rng(3)
    for model, hand in ((vj.models.UnderwaterVehicle(), vehicle_field), (vj.models.HeavyTop(), heavy_top_field)):
        ours = jax.jit(lambda y, m=model: continuous.vector_field(m).vf(0.0, y, None))
        fields = [jax.jit(lambda y, m=model, e=e: hand(m, elementwise=e).vf(0.0, y, None)) for e in (True, False)]
        for y in _states(model, rng):
            for f in fields:
                _assert_close(f(y), ours(y), _scale(model, y))


def test_float32_field():
    """Scene and state in float32: the field stays float32 (H, H⁻¹ are cast to the state's dtype)
    and agrees with float64 to float32 round-off: (k + κ(H))·eps32 ≈ 90·6e-8 ≈ 5e-6 (module
    docstring, inputs rounded to float32 included), so 1e-4·S leaves a margin of ~20."""
    f32 = lambda x: None if x is None else jnp.asarray(x, jnp.float32)  # noqa: E731
    model = vj.models.UnderwaterVehicle()
    model32 = jax.tree.map(f32, model)
    y = _states(model, np.random.default_rng(4), 1)[0]
    ours = continuous.time_derivative(model32, jax.tree.map(f32, y))
    assert all(x.dtype == jnp.float32 for x in ours)
    _assert_close(ours, reference(model, y), 1e8 * _scale(model, y))
