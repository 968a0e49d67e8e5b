"""The Clebsch–Cayley rigid-body integrator of seed 002 (Theorem 28 corrected, Example 31) and its
Lie–Poisson form: order, exact invariants, the O(h²) negative control, SO(4) spectrum, the
agreement of both forms, and the equivalence with the generic DEP–Cayley step (Remark 32)."""

import functools

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj
from vi_jax.lie import SOn
from vi_jax.models import clebsch

BODY = vj.models.RigidBody(inertia=(0.5, 0.6, 1.0))
SO4_BODY = vj.models.RigidBody(group=SOn(4), mass_matrix=(0.6, 0.45, 0.3, 0.1))
H = 0.1
N = 10_000  # one compiled run per (group, form), shared by the tests below
N_EQUIV = 1000  # nodes compared between implementations (trajectories separate at round-off rate)
EPS = np.finfo(np.float64).eps


def round_off(n, scale=1.0, eps=EPS):
    """Bound on the drift of a quantity the scheme conserves exactly, after n steps: each step
    rounds it by a few ε·scale, uncorrelated from step to step, so the errors add like a random
    walk: 30·√n·ε·scale covers a 6ε step at 5σ (measured ≤ 2.7·√n·ε here, on two machines). A
    bias of one ε per step would cross it after 900 steps."""
    return 30 * np.sqrt(n) * eps * scale


def separation(n, rate, scale):
    """Bound on the distance after n steps of two roundings of the same map (another formula,
    vmap, a generic engine): their invariants part like a random walk (√n·ε), which the flow
    shears into a phase error growing like rate·t, rate = |Ω| (measured ≤ 0.04 of this)."""
    return 10 * EPS * np.sqrt(n) * (1 + rate * n * H) * scale


def unit_momentum_state(body, omega):
    """Initial data with |𝕀Ω(0)| = 1 (the Casimir sphere of Figure 1)."""
    omega = jnp.asarray(omega, float)
    return body.initial_state(omega0=omega / jnp.linalg.norm(body.inertia @ omega))


CASES = {
    "SO3": (BODY, unit_momentum_state(BODY, (1.0, 0.5, -0.3))),
    "SO4": (SO4_BODY, unit_momentum_state(SO4_BODY, (0.7, -0.4, 0.9, 0.5, -0.8, 0.3))),
}
X0 = CASES["SO3"][1]


@functools.cache
def run(case, form):
    body, x0 = CASES[case]
    return clebsch.simulate(body, x0, H, N, form=form)


def reference(T):
    """Q(T), Π(T) of Π̇ = Π×Ω, Q̇ = QΩ̂ (Tsit5, tolerances 1e-12)."""
    inertia_inv = jnp.linalg.inv(BODY.inertia)

    def field(t, y, args):
        Q, Pi = y
        omega = inertia_inv @ Pi
        return Q @ BODY.group.hat(omega), jnp.cross(Pi, omega)

    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field), diffrax.Tsit5(), 0.0, T, 0.01, (X0.g, BODY.inertia @ X0.xi),
        stepsize_controller=diffrax.PIDController(rtol=1e-12, atol=1e-12), max_steps=100_000,
    )
    return sol.ys[0][-1], sol.ys[1][-1]


def relative_drift(vectors):
    """max_k ‖v_k − v_0‖ / ‖v_0‖."""
    vectors = np.asarray(vectors)
    return np.max(np.linalg.norm(vectors - vectors[0], axis=-1)) / np.linalg.norm(vectors[0])


HS = np.array([0.1, 0.05, 0.025, 0.0125])


@functools.cache
def run_over_h():
    """2000 steps for each h in HS: one compiled run, vmapped over h."""
    sols = jax.vmap(lambda h: clebsch.simulate(BODY, X0, h, 2000, throw=False))(jnp.asarray(HS))
    assert bool(jnp.all(sols.result == 0))
    return sols


def test_order_two_with_consistent_initialisation():
    """μ̃₀ = Π(0): Q^k → Q(t_k) and μ̃_k → Π(t_k) at order 2 (spec §3, option (b));
    node T/h is compared with the reference at T."""
    T = 4.0
    Q_ref, Pi_ref = reference(T)
    sols = run_over_h()
    k, i = np.rint(T / HS).astype(int), np.arange(len(HS))
    err_Q = np.max(np.abs(np.asarray(sols.Q[i, k]) - np.asarray(Q_ref)), axis=(1, 2))
    err_mu = np.max(np.abs(np.asarray(sols.mu[i, k]) - np.asarray(Pi_ref)), axis=1)
    for err in (err_Q, err_mu):
        slope = np.polyfit(np.log(HS), np.log(err), 1)[0]
        assert abs(slope - 2.0) <= 0.1, (slope, err)


@pytest.mark.parametrize("form", clebsch.FORMS)
def test_exact_invariants_over_ten_thousand_steps(form):
    """|μ̃| and the spatial momentum Q μ̃ Qᵀ to round-off; Q ∈ SO(3); energy bounded, no drift."""
    sol = run("SO3", form)
    norms = np.linalg.norm(np.asarray(sol.mu), axis=1)
    assert np.max(np.abs(norms / norms[0] - 1)) <= round_off(N)  # measured ≤ 0.9·√N·ε
    assert relative_drift(sol.spatial) <= round_off(N)  # measured ≤ 1.1·√N·ε
    assert float(jnp.max(vj.group_constraint_residual(BODY, sol.Q))) <= 1e-12
    energy = np.asarray(sol.energy) / float(sol.energy[0]) - 1
    assert np.max(np.abs(energy)) <= 1e-3
    slope = np.polyfit(np.asarray(sol.t), energy, 1)[0]
    assert abs(slope) * float(sol.t[-1]) <= 0.05 * np.ptp(energy)
    assert np.max(np.asarray(sol.newton_residual)) <= 1e-13  # Newton's stopping test: ≤ rtol = 64ε
    if form == "clebsch":  # eq. (18): Proj(QᵀP) = 𝕀X
        M = jnp.einsum("kji,kjl->kil", sol.Q, sol.P)
        np.testing.assert_allclose(jax.vmap(BODY.group.vee)(M), sol.Pi, rtol=0, atol=1e-13)


def test_lagrangian_momentum_moves_at_order_two():
    """Negative control: |𝕀X^k| (the Clebsch momentum map Proj QᵀP) is not conserved; its
    deviation from |μ̃₀| = 1 over 2000 steps (≥ 10 periods) is ~1e-2 at h = 0.1 and 4× smaller
    at h/2."""
    norms = np.linalg.norm(np.asarray(run_over_h().Pi), axis=2)
    deviation = dict(zip(HS, np.max(np.abs(norms - 1), axis=1)))
    assert 3e-3 <= deviation[0.1] <= 3e-2
    assert 3.6 <= deviation[0.1] / deviation[0.05] <= 4.4


def spectrum_so4(mu):
    """The singular values σ₁ ≥ σ₂ of μ̂ (its eigenvalues are ±iσ₁, ±iσ₂), per node."""
    return np.linalg.svd(np.asarray(jax.vmap(SO4_BODY.group.hat)(mu)), compute_uv=False)[:, ::2]


@pytest.mark.parametrize("form", clebsch.FORMS)
def test_spectrum_of_momentum_conserved_on_so4(form):
    """The spectrum of μ̃ (all Casimirs of so(4)*) and the spatial momentum to round-off over
    10⁴ steps; Q ∈ SO(4). Control: the spectrum of the Clebsch momentum 𝕀X moves."""
    sol = run("SO4", form)
    spectrum = spectrum_so4(sol.mu)
    assert np.max(np.abs(spectrum - spectrum[0])) <= round_off(N, spectrum[0, 0])  # measured ≤ 1.2·√N·ε
    assert relative_drift(sol.spatial) <= round_off(N)  # measured ≤ 2.7·√N·ε
    assert float(jnp.max(vj.group_constraint_residual(SO4_BODY, sol.Q))) <= 1e-12
    spectrum_Pi = spectrum_so4(sol.Pi)
    assert np.max(np.abs(spectrum_Pi - spectrum_Pi[0])) >= 1e-5 * spectrum_Pi[0, 0]


@pytest.mark.parametrize("case", CASES)
def test_clebsch_form_equals_lie_poisson_form(case):
    """Theorem 28 (ambient P, corrected transpose) and the reduced form give the same X^k."""
    a, b = run(case, "lie_poisson"), run(case, "clebsch")
    rate = float(jnp.max(jnp.abs(a.omega)))
    for x, y in ((a.omega, b.omega), (a.Q, b.Q), (a.mu, b.mu)):
        gap = float(jnp.max(jnp.abs(x[:N_EQUIV] - y[:N_EQUIV])))
        assert gap <= separation(N_EQUIV, rate, float(jnp.max(jnp.abs(x)))), gap
    M = jnp.einsum("kji,kjl->kil", b.Q, b.P)
    skew = float(jnp.max(jnp.abs(M + jnp.swapaxes(M, 1, 2))))  # congruences keep QᵀP skew
    assert skew <= round_off(N, float(jnp.max(jnp.abs(M)))), skew  # measured ≤ 1.7·√N·ε


@pytest.mark.parametrize("case,order", [("SO3", 1), ("SO3", 2), ("SO4", 2)])
def test_equals_generic_dep_cayley_step(case, order):
    """Remark 32: the Clebsch integrator is the DEP–Cayley integrator of
    L_d = h l(cay⁻¹(g_k⁻¹g_{k+1})/h); the engine's left (order 1) and trapezoid (order 2) rules
    coincide for l = l(ξ), and its discrete momentum M_k is μ̃_k."""
    body, x0 = CASES[case]
    ours = run(case, "lie_poisson")
    engine = vj.simulate(body, x0, H, N_EQUIV, tau="cayley", order=order)
    rate = float(jnp.max(jnp.abs(engine.xi)))
    for x, y in ((ours.Q[: N_EQUIV + 1], engine.g), (ours.mu[: N_EQUIV + 1], engine.M)):
        gap = float(jnp.max(jnp.abs(x - y)))
        assert gap <= separation(N_EQUIV, rate, float(jnp.max(jnp.abs(y)))), gap


def test_vmap_over_initial_data_equals_single_run():
    omegas = jnp.stack([X0.xi, jnp.array([0.1, 1.2, 0.2]), jnp.array([-0.5, 0.1, 0.8])])
    batched = jax.vmap(lambda w: clebsch.simulate(BODY, vj.State(X0.g, w), H, N, throw=False))(omegas)
    assert bool(jnp.all(batched.result == 0))
    single = run("SO3", "lie_poisson")
    # batching may reorder XLA's arithmetic (it does not on CPU today: equal bits)
    rate = float(jnp.max(jnp.abs(single.omega)))
    np.testing.assert_allclose(batched.mu[0], single.mu, rtol=0, atol=separation(N, rate, 1.0))
    np.testing.assert_allclose(batched.Q[0], single.Q, rtol=0, atol=separation(N, rate, 1.0))


def test_implicit_gradient_matches_finite_differences():
    """The gradient of a loss on Q^N with respect to the inertia, through the Newton solves
    (implicit-function theorem), matches central finite differences."""

    def loss(inertia_diag):
        body = vj.models.RigidBody(inertia=inertia_diag)
        Q = clebsch.simulate(body, X0, H, 50, throw=False).Q[-1]
        return jnp.sum(Q[:, 0] ** 2 * jnp.arange(1.0, 4.0))

    p = jnp.array([0.5, 0.6, 1.0])
    grad = jax.jit(jax.grad(loss))(p)
    eps = 1e-6
    fd = jnp.array([(loss(p + eps * e) - loss(p - eps * e)) / (2 * eps) for e in jnp.eye(3)])
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize(
    "kwargs,argument",
    [
        (dict(body=vj.models.HeavyTop()), "body"),
        (dict(form="midpoint"), "form"),
        (dict(h=-0.1), "h"),
        (dict(n_steps=0), "n_steps"),
        (dict(x0=vj.State(jnp.eye(4), jnp.zeros(3))), "x0.g"),
    ],
)
def test_invalid_input_names_argument(kwargs, argument):
    args = dict(body=BODY, x0=X0, h=H, n_steps=10, form="lie_poisson") | kwargs
    with pytest.raises(ValueError, match=argument):
        clebsch.simulate(**args)


def test_float32_runs_at_its_precision():
    x0 = vj.State(jnp.asarray(X0.g, jnp.float32), jnp.asarray(X0.xi, jnp.float32))
    sol = clebsch.simulate(BODY, x0, np.float32(H), 1000)
    assert sol.mu.dtype == sol.Q.dtype == jnp.float32
    norms = np.linalg.norm(np.asarray(sol.mu), axis=1)
    # measured 10ε₃₂ = 0.3·√n·ε₃₂; TF32 products (unit round-off 2⁻¹¹ ≈ 4e-4, 4× the bound) fail it
    assert np.max(np.abs(norms / norms[0] - 1)) <= round_off(1000, eps=np.finfo(np.float32).eps)
