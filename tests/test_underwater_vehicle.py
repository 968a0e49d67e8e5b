"""The underwater vehicle of seed 000 through the generic engine: initial data, the paper's
schemes reproduced, conservation on the paper's run, convergence order."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj
from hand_vehicle import eq65, node_diagnostics_hand, simulate_hand, vehicle_params

MODEL = vj.models.UnderwaterVehicle()
X0 = MODEL.initial_state()


def test_table_2_initial_data():
    # ZXZ angles (2π, 0, 2π): sin(fl(2π)) = −2.4e-16 ≠ 0, so R₀ = I up to 2|sin(fl(2π))| off the diagonal
    np.testing.assert_allclose(X0.g, np.eye(3), atol=3 * abs(np.sin(2 * np.pi)))
    np.testing.assert_allclose(X0.xi, [np.pi / 18, 0.0, np.pi / 9], atol=1e-15)
    sol = vj.simulate(MODEL, X0, 0.01, 1)
    # Reference values from the seed 000 spec §4 (E₀ = 58.772042883837685 J, I₀ = J₃ω_z).
    assert abs(float(sol.energy[0]) - 58.772042883837685) < 1e-10
    assert abs(float(sol.kelvin_noether[0]) - 5.72 * np.pi / 9) < 1e-13


@pytest.mark.parametrize("tau", ["cayley", "exp"])
def test_engine_equals_paper_vectorised_scheme(tau):
    """Generic F⁻/F⁺ step with the left rule (eq. 71) ≡ the paper's eqs. 73–74 with (88) / (97)."""
    n = 1000  # ≤ 1024 saved nodes: the program other tests of this scene compile
    R, q, M, P = jax.jit(simulate_hand, static_argnums=(6, 7))(
        vehicle_params(MODEL), X0.g, X0.q, X0.xi, X0.qdot, 0.01, n, tau
    )
    sol = vj.simulate(MODEL, X0, 0.01, n, tau=tau, order=1)
    for ours, theirs in ((sol.q, q), (sol.R, R), (sol.M, M), (sol.P, P)):
        rel = np.max(np.abs(ours[1:] - theirs)) / np.max(np.abs(theirs))
        assert rel <= 1e-10


@pytest.mark.parametrize("tau", ["cayley", "exp"])
def test_paper_run_conservation(tau):
    """[0, 500] s at h = 0.01: Kelvin–Noether to round-off, R ∈ SO(3), energy at Figure 1 level,
    and q(500) at the spec's anchors (first-order scheme, Legendre initialisation)."""
    sol = vj.simulate(MODEL, X0, 0.01, 50_000, tau=tau)
    I = np.asarray(sol.kelvin_noether)
    assert np.max(np.abs(I - I[0])) <= 1e-13 * np.max(np.asarray(sol.kelvin_noether_scale))
    assert np.max(np.abs(I - I[0])) / abs(I[0]) <= 1e-9
    assert float(jnp.max(vj.group_constraint_residual(MODEL, sol.R))) <= 1e-12
    rel_energy = np.abs(np.asarray(sol.energy) / float(sol.energy[0]) - 1)
    assert rel_energy.max() <= 5e-4
    assert abs(rel_energy.max() - 4.28e-4) <= 0.02e-4
    anchors = {"cayley": (48.5430303, 49.8299061, -430.3007982), "exp": (48.5430321, 49.8299091, -430.3007981)}
    np.testing.assert_allclose(sol.q[-1], anchors[tau], atol=1e-5)
    assert np.max(np.asarray(sol.newton_residual)) <= 1e-13


def test_bounded_motion_energy_has_no_drift():
    """Neutral buoyancy (W = B): bounded rotational motion, 10⁵ steps, energy error oscillates
    with no secular trend (least-squares slope × T ≪ the oscillation amplitude)."""
    model = vj.models.UnderwaterVehicle(buoyancy=123.8 * 9.81)
    x0 = model.initial_state(omega0=jnp.array([0.6, -0.4, 0.8]))
    sol = vj.simulate(model, x0, 0.02, 100_000, save_every=10)
    t = np.asarray(sol.t)
    err = np.asarray(sol.energy) / float(sol.energy[0]) - 1
    slope = np.polyfit(t, err, 1)[0]
    amplitude = np.max(np.abs(err))
    assert amplitude > 1e-8  # the first-order scheme does show an O(h) energy oscillation
    assert abs(slope) * t[-1] <= 0.05 * amplitude


def _eq65(t, y, args):
    R, q, w, nu = y[:9].reshape(3, 3), y[9:12], y[12:15], y[15:18]
    dR, dw, dq, dnu = eq65(MODEL, R, w, q, nu)
    return jnp.concatenate([dR.ravel(), dq, dw, dnu])


def reference_q(T):
    y0 = jnp.concatenate([X0.g.ravel(), X0.q, X0.xi, X0.g.T @ X0.qdot])
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(_eq65), diffrax.Dopri8(), 0.0, T, 0.01, y0,
        stepsize_controller=diffrax.PIDController(rtol=1e-13, atol=1e-13), max_steps=100_000,
    )
    return np.asarray(sol.ys[-1, 9:12])


def test_paper_rule_is_first_order():
    T = 20.0
    q_ref = reference_q(T)
    hs = np.array([0.04, 0.02, 0.01, 0.005])
    # the final node only (save_every = n): one compiled program serves every step size
    steps = [int(round(T / h)) for h in hs]
    errors = [np.linalg.norm(np.asarray(vj.simulate(MODEL, X0, h, n, save_every=n).q[-1]) - q_ref) for h, n in zip(hs, steps)]
    slope = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    assert 0.9 <= slope <= 1.1


def test_node_diagnostics_equal_hand_formulas():
    """Every node's velocities, energy, Kelvin–Noether quantity and its scale equal eq. (62)'s
    written out by hand on the same saved (R, q, M, P) — the engine derives them by autodiff and a
    Newton solve of the Legendre map; both are a few operations on O(1) values: ≤ 1e-13 relative."""
    sol = vj.simulate(MODEL, X0, 0.05, 1000, order=2)
    theirs = node_diagnostics_hand(vehicle_params(MODEL), sol.R, sol.q, sol.M, sol.P)
    ours = (sol.omega, sol.nu, sol.energy, sol.kelvin_noether, sol.kelvin_noether_scale)
    for name, x, y in zip(("omega", "nu", "energy", "kelvin_noether", "scale"), ours, theirs):
        assert np.max(np.abs(np.asarray(x) - np.asarray(y))) <= 1e-13 * np.max(np.abs(np.asarray(y))), name
