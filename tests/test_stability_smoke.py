"""A tiny version of benchmarks/stability.py: the behaviour it measured at and past the
difference maps' limits and at near-singular data (values and gradients)."""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj

H = 0.1
N_STEPS = 100
DIRECTION = np.array([1.0, 0.5, -0.3]) / np.linalg.norm([1.0, 0.5, -0.3])
# |hω₀|: far past Cayley's accuracy limit π, past exp's singular set, well inside, ω₀ = 0, 1e-12.
HW = np.array([20.0, 4.0, 0.1, 0.0, 1e-13])


def _run(tau):
    body = vj.models.RigidBody()

    def loss(omega, h):
        sol = vj.simulate(body, vj.State(g=jnp.eye(3), xi=omega), h, N_STEPS, tau=tau, order=2, throw=False)
        e = sol.energy
        aux = dict(
            result=sol.result,
            group=jnp.max(vj.group_constraint_residual(body, sol.g)),
            energy=jnp.max(jnp.abs(e - e[0])) / jnp.maximum(jnp.abs(e[0]), 1e-300),
        )
        return jnp.sum(sol.g[-1]) + jnp.sum(sol.xi[-1]) + jnp.sum(e), aux

    fn = jax.jit(jax.vmap(jax.value_and_grad(loss, argnums=(0, 1), has_aux=True)))
    (value, aux), (g_omega, g_h) = fn(jnp.asarray(HW[:, None] / H * DIRECTION), jnp.full(len(HW), H))
    return value, jax.tree.map(np.asarray, aux), np.asarray(g_omega), np.asarray(g_h)


@pytest.fixture(scope="module")
def cayley():
    return _run("cayley")


@pytest.fixture(scope="module")
def exp():
    return _run("exp")


def test_cayley_far_past_pi_stays_on_group_and_bounded(cayley):
    _, aux, _, _ = cayley
    assert np.all(aux["result"][0] == 0)
    assert aux["group"][0] < 1e-12
    assert aux["energy"][0] < 0.1  # measured ≈ 0.04: bounded, inaccurate


def test_exp_past_pi_is_flagged_singular(exp):
    _, aux, _, _ = exp
    assert np.any(aux["result"][1] == 3)  # |hω| = 4 ≥ π
    assert np.all(aux["result"][2] == 0) and aux["energy"][2] < 1e-4


@pytest.mark.parametrize("case", [3, 4], ids=["omega=0", "omega=1e-12"])
@pytest.mark.parametrize("tau", ["cayley", "exp"])
def test_zero_spin_values_and_gradients_finite(cayley, exp, case, tau):
    value, aux, g_omega, g_h = {"cayley": cayley, "exp": exp}[tau]
    assert np.all(aux["result"][case] == 0)
    assert np.isfinite(value[case])
    assert np.all(np.isfinite(g_omega[case])) and np.isfinite(g_h[case])
    # At (nearly) rest nothing moves, whatever h: the h-gradient is (nearly) zero.
    assert abs(g_h[case]) < 1e-9


def test_top_exactly_upright_stays_upright():
    top = vj.models.HeavyTop()
    x0 = top.initial_state(R0=np.eye(3), omega0=np.array([0.0, 0.0, 6.0]))
    sol = vj.simulate(top, x0, 0.01, 200, tau="cayley", order=2)
    gamma = np.asarray(sol.R[:, 2, :])  # Γ = Rᵀe₃
    assert np.max(np.abs(gamma - np.array([0.0, 0.0, 1.0]))) < 1e-13
    assert np.max(np.abs(np.asarray(sol.omega) - np.array([0.0, 0.0, 6.0]))) < 1e-12


def test_the_damped_newton_prototype_stands_in_for_the_engines():
    """benchmarks/stability.py swaps ``dep_step``'s Newton for the damped prototype of
    benchmarks/_stability_newton.py: it must take every argument the engine passes (the
    vehicle's explicit unknowns included) and find the same root, to Newton's tolerance per step
    (64ε, a √n random walk, a factor 4 for its tail)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from _stability_newton import patched

    model = vj.models.UnderwaterVehicle()
    x0, n_steps = model.initial_state(), 20
    run = lambda: jax.jit(lambda x: vj.simulate(model, x, 0.01, n_steps))(x0)  # noqa: E731
    engine = run()
    with patched():
        damped = run()
    bound = 4 * 64 * np.finfo(np.float64).eps * np.sqrt(n_steps)
    for field in ("g", "q", "M", "P"):
        ours, theirs = np.asarray(getattr(damped, field)), np.asarray(getattr(engine, field))
        assert np.max(np.abs(ours - theirs)) <= bound * max(np.max(np.abs(theirs)), 1.0), field
