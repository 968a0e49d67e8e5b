"""Property tests over every group of the Lie layer and both difference maps."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from vi_jax import lie

GROUPS = [lie.SO3(), lie.SE3(), lie.SOn(2), lie.SOn(3), lie.SOn(4), lie.SOn(5), lie.Rn(1), lie.Rn(3)]
TAUS = [lie.Cayley(), lie.Exp()]
ids = lambda x: type(x).__name__ + str(getattr(x, "n", ""))  # noqa: E731
EPS = np.finfo(np.float64).eps

settings.register_profile("vi_jax", max_examples=15, deadline=None)
settings.load_profile("vi_jax")


def vectors(group, scale=1.0):
    return st.lists(
        st.floats(-scale, scale, allow_nan=False, allow_subnormal=False), min_size=group.dim, max_size=group.dim
    ).map(lambda v: jnp.asarray(v, jnp.float64))


def close(a, b, tol):
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=tol)


@functools.cache
def tau_errors(group, tau):
    """Jitted: the defining identities of a difference map, as residuals (one compile per pair)."""

    @jax.jit
    def errors(x):
        eye = jnp.eye(group.matrix_size)
        g = tau.tau(group, x)
        T = group.right_trivialised_tangent(lambda y: tau.tau(group, y), x)
        return {
            "tau(0) = e": jnp.abs(tau.tau(group, jnp.zeros_like(x)) - eye).max(),
            "tau(x) in G": group.membership_error(g),
            "tau(-x) = tau(x)^-1": jnp.abs(tau.tau(group, -x) @ g - eye).max(),
            "tau_inv(tau(x)) = x": jnp.abs(tau.tau_inv(group, g) - x).max(),
            "dtau_inv = T^-1 (autodiff)": jnp.abs(tau.dtau_inv(group, x) @ T - jnp.eye(group.dim)).max(),
            "eq. 35": jnp.abs(
                tau.dtau_inv(group, x) - tau.dtau_inv(group, -x) @ group.Ad(tau.tau(group, -x))
            ).max(),
        }

    return errors


@pytest.mark.parametrize("group", GROUPS, ids=ids)
@pytest.mark.parametrize("tau", TAUS, ids=lambda t: t.name)
@given(data=st.data())
def test_difference_map_axioms(group, tau, data):
    # exp⁻¹ inverts exp only inside |θ| < π: the rotation angles of x obey Σθᵢ² ≤ |x|² ≤ dim·s²,
    # so s = 0.8π/√dim keeps every angle ≤ 0.8π (s = 1.2 let SO(5) reach 3.7 > π).
    scale = 1.2 if isinstance(tau, lie.Cayley) else min(1.2, 0.8 * np.pi / np.sqrt(group.dim))
    x = data.draw(vectors(group, scale))
    errors = tau_errors(group, tau)(x)
    for name, err in errors.items():
        assert float(err) <= (1e-11 if name.startswith("tau_inv") else 1e-12), name


@functools.cache
def group_errors(group):
    @jax.jit
    def errors(x, y, eta, mu):
        g, k = group.exp(x), group.exp(y)
        eye = jnp.eye(group.matrix_size)
        d_Ad = jax.jvp(lambda t: group.Ad(group.exp(t * x)) @ eta, (0.0,), (1.0,))[1]
        jacobi = (
            group.bracket(x, group.bracket(y, eta))
            + group.bracket(y, group.bracket(eta, x))
            + group.bracket(eta, group.bracket(x, y))
        )
        return {
            "g g^-1 = e": jnp.abs(group.compose(g, group.inverse(g)) - eye).max(),
            "closure": group.membership_error(group.compose(g, k)),
            "vee(hat) exact": jnp.abs(group.vee(group.hat(eta)) - eta).max(),
            "Ad homomorphism": jnp.abs(group.Ad(g @ k) - group.Ad(g) @ group.Ad(k)).max(),
            "Ad = conjugation": jnp.abs(group.Ad(g) @ eta - group.vee(g @ group.hat(eta) @ group.inverse(g))).max(),
            "ad = d Ad": jnp.abs(group.ad(x) @ eta - d_Ad).max(),
            "ad = bracket": jnp.abs(group.ad(x) @ eta - group.bracket(x, eta)).max(),
            "ad* dual": jnp.abs(group.ad_dual(x, mu) @ eta - mu @ group.bracket(x, eta)),
            "Ad*_{g^-1}": jnp.abs(group.Ad_dual_inv(g, mu) - group.Ad(group.inverse(g)).T @ mu).max(),
            "Jacobi": jnp.abs(jacobi).max(),
        }

    return errors


@pytest.mark.parametrize("group", GROUPS, ids=ids)
@given(data=st.data())
def test_group_axioms_and_adjoint(group, data):
    args = [data.draw(vectors(group)) for _ in range(4)]
    for name, err in group_errors(group)(*args).items():
        assert float(err) <= (0.0 if name == "vee(hat) exact" else 1e-12), name


@pytest.mark.parametrize("group", [g for g in GROUPS if not isinstance(g, lie.Rn)], ids=ids)
@given(data=st.data())
def test_diamond_defining_identity(group, data):
    """⟨b◇x, η⟩ = −⟨b, ρ'(η)x⟩ for the standard action and for a user representation."""
    d = group.matrix_size
    eta = data.draw(vectors(group))
    x = jnp.asarray(data.draw(st.lists(st.floats(-1, 1, allow_subnormal=False), min_size=d, max_size=d)))
    b = jnp.asarray(data.draw(st.lists(st.floats(-1, 1, allow_subnormal=False), min_size=d, max_size=d)))
    for action in (lie.LinearAction(group), lie.LinearAction(group, rho=lambda g: jnp.kron(g, g))):
        xx = x if action.rho is None else jnp.kron(x, x)
        bb = b if action.rho is None else jnp.kron(b, b)
        lhs = action.diamond(bb, xx) @ eta
        close(lhs, -bb @ action.infinitesimal(eta, xx), 1e-12)


def test_so3_diamond_is_cross_product():
    action = lie.LinearAction(lie.SO3())
    b, x = jnp.array([0.3, -1.2, 0.7]), jnp.array([1.1, 0.4, -0.5])
    # each component is a difference of two products on both sides: ≤ 2ε|b||x| apart
    close(action.diamond(b, x), jnp.cross(b, x), 2 * EPS * float(jnp.linalg.norm(b) * jnp.linalg.norm(x)))


def test_isotropy_of_vertical_direction():
    basis = lie.LinearAction(lie.SO3()).isotropy_basis(np.array([0.0, 0.0, 1.0]))
    # LAPACK's SVD: null vector within p(n)·ε‖C‖/gap, here ‖C‖ = gap = 1, n = 3 (p(n) ≈ 10n)
    close(jnp.abs(basis[:, 0]), jnp.array([0.0, 0.0, 1.0]), 30 * EPS)


@pytest.mark.parametrize("tau", TAUS, ids=lambda t: t.name)
@pytest.mark.parametrize("group", [lie.SO3(), lie.SE3(), lie.SOn(4)], ids=ids)
def test_values_and_gradients_finite_at_zero(group, tau):
    def f(x):
        return jnp.sum(tau.tau(group, x)) + jnp.sum(tau.dtau_inv(group, x))

    def round_trip(x):
        return jnp.sum(tau.tau_inv(group, tau.tau(group, x)))

    def hessian_times_ones(x):
        # a NaN or inf anywhere in the Hessian reaches H·1 (NaN·0 = inf·0 = NaN): the same
        # finiteness check as the full Hessian at a fraction of its compile time (SO(4) exp)
        return jax.jvp(jax.grad(f), (x,), (jnp.ones_like(x),))[1]

    zero = jnp.zeros(group.dim)
    checks = jax.jit(lambda x: (f(x), jax.grad(f)(x), hessian_times_ones(x), jax.grad(round_trip)(x)))(zero)
    for value in checks:
        assert np.all(np.isfinite(value))
    np.testing.assert_allclose(checks[3], np.ones(group.dim), atol=1e-12)  # d(τ⁻¹∘τ) = id


@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_son_exp_and_log_match_scipy(n):
    """SO(n)'s scaled-Taylor exp against scipy's Padé expm, and its series log inverting it."""
    import scipy.linalg

    group = lie.SOn(n)
    exp, log = jax.jit(group.exp), jax.jit(group.log)
    rng = np.random.default_rng(n)
    for scale in (1e-6, 0.1, 1.0, 10.0, 300.0):
        x = rng.normal(size=group.dim) * scale / np.sqrt(group.dim)
        X = np.asarray(group.hat(jnp.asarray(x)))
        # scaling and squaring: the 2^s squarings (2^s ≤ 4‖X‖_F) amplify a few ulps of error
        # in either method ∝ ‖X‖_F; 64ε(1 + ‖X‖_F) leaves 4× room over the worst measured
        close(exp(jnp.asarray(x)), scipy.linalg.expm(X), 64 * EPS * (1 + np.linalg.norm(X)))
        y = x * min(1.0, 3.0 / np.linalg.norm(x))  # every rotation angle < π: log's domain
        # log inverts exp's result, which carries exp's error (the bound above, at ‖Y‖_F): an
        # angle near π moves by as much as the matrix entries (SO(2), y = 3: 66ε measured)
        close(log(exp(jnp.asarray(y))), y, 64 * EPS * (1 + np.linalg.norm(group.hat(jnp.asarray(y)))))


def test_dexp_alpha_series_matches_closed_form():
    """α(θ) series and closed form agree on θ ∈ [0.08, 0.12] (both sides of the switch)."""
    from vi_jax.lie._series import dexp_inv_alpha

    theta = np.linspace(0.08, 0.12, 41)
    closed = (1 - (theta / 2) / np.tan(theta / 2)) / theta**2
    # a closed form cancels 1 − (θ/2)cot(θ/2) ≈ θ²/12, so it errs by a few ulps of tan over θ²:
    # ≲ 4ε/θ² for numpy's and for XLA's (above the switch); the series' truncation (θ⁸/4.8e7 ≤
    # 1e-16) and rounding (≈ ε/12) are far below
    err = np.abs(np.asarray(dexp_inv_alpha(jnp.asarray(theta**2))) - closed)
    assert np.all(err <= 8 * EPS / theta**2), np.max(err * theta**2 / EPS)
    assert float(jax.grad(lambda x: dexp_inv_alpha(x @ x))(jnp.zeros(3)) @ jnp.ones(3)) == 0.0


def test_exp_singular_set_detected():
    group, tau = lie.SO3(), lie.Exp()
    assert bool(tau.is_regular(group, jnp.array([0.0, 0.0, 3.0])))
    assert not bool(tau.is_regular(group, jnp.array([0.0, 0.0, 3.2])))
    assert not bool(tau.is_regular(group, jnp.array([0.0, 2 * jnp.pi, 0.0])))
    assert bool(lie.Cayley().is_regular(group, jnp.array([0.0, 0.0, 50.0])))


def test_so3_closed_forms_match_generic_autodiff():
    x = jnp.array([0.4, -0.9, 1.3])
    generic = lie.SOn(3)
    # SOn(3) uses the ordering (x01, x02, x12); map SO(3) coordinates onto it.
    P = jnp.array([[0, 0, 1], [0, -1, 0], [1, 0, 0]], float)  # x̂_SO3 = hat_SOn(P x)
    close(lie.SO3().hat(x), generic.hat(P @ x), 0.0)
    for name in ("cay", "exp"):
        close(getattr(lie.SO3(), name)(x), getattr(generic, name)(P @ x), 1e-13)
    close(lie.SO3().dcay_inv(x), P @ generic.dcay_inv(P @ x) @ P, 1e-13)
    close(lie.SO3().dexp_inv(x), P @ generic.dexp_inv(P @ x) @ P, 1e-12)
    # the dual maps in vector form (eqs. 88, 97), against the generic transposed matrices
    mu = jnp.array([0.3, 1.1, -0.5])
    for scale in (1e-9, 1.0, 2.0):
        close(lie.SO3().dcay_inv_dual(scale * x, mu), P @ generic.dcay_inv_dual(scale * P @ x, P @ mu), 1e-13)
        close(lie.SO3().dexp_inv_dual(scale * x, mu), P @ generic.dexp_inv_dual(scale * P @ x, P @ mu), 1e-12)


def test_se3_closed_forms_match_generic_autodiff():
    x = jnp.array([0.4, -0.9, 1.3, 0.2, 2.0, -0.7])
    group = lie.SE3()
    close(group.cay(x), jnp.linalg.solve(jnp.eye(4) - group.hat(x) / 2, jnp.eye(4) + group.hat(x) / 2), 1e-13)
    close(group.exp(x), jax.scipy.linalg.expm(group.hat(x)), 1e-12)
    for tau, closed in ((group.cay, group.dcay_inv), (group.exp, group.dexp_inv)):
        close(closed(x), jnp.linalg.inv(group.right_trivialised_tangent(tau, x)), 1e-12)
