"""Orders of the variational schemes (1: the paper's rule; 2: trapezoid; 4, 6: compositions)
against a tight continuous reference, and Kelvin–Noether to round-off for every order."""

import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj
from vi_jax import continuous

CASES = {
    # system, T, step sizes per order (errors well above the reference's ~1e-12)
    "vehicle": (vj.models.UnderwaterVehicle(), 20.0, {1: (0.04, 0.02, 0.01), 2: (0.2, 0.1, 0.05), 4: (0.4, 0.2, 0.1), 6: (0.4, 0.2, 0.1)}),
    "heavy top": (vj.models.HeavyTop(), 1.0, {1: (0.01, 0.005, 0.0025), 2: (0.02, 0.01, 0.005), 4: (0.02, 0.01, 0.005), 6: (0.05, 0.025, 0.0125)}),
}
_REFERENCES = {}


def reference(name):
    if name not in _REFERENCES:
        system, T, _ = CASES[name]
        sol = continuous.solve(system, system.initial_state(), T, rtol=1e-14, atol=1e-14, dt0=1e-3)
        _REFERENCES[name] = jnp.asarray(sol.ys[0][-1]), None if sol.ys[2] is None else jnp.asarray(sol.ys[2][-1])
    return _REFERENCES[name]


def final_error(system, T, h, order, g_ref, q_ref):
    n = int(round(T / h))
    sol = vj.simulate(system, system.initial_state(), h, n, order=order, save_every=n)
    err = float(jnp.max(jnp.abs(sol.g[-1] - g_ref)))
    if q_ref is not None:
        err = max(err, float(jnp.max(jnp.abs(sol.q[-1] - q_ref))))
    return err


@pytest.mark.parametrize("order", [1, 2, 4, 6])
@pytest.mark.parametrize("name", list(CASES))
def test_convergence_order(name, order):
    system, T, steps = CASES[name]
    g_ref, q_ref = reference(name)
    hs = np.array(steps[order])
    errors = np.array([final_error(system, T, h, order, g_ref, q_ref) for h in hs])
    slope = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    assert abs(slope - order) <= 0.15, (errors, slope)


@pytest.mark.parametrize("order", [2, 4, 6])
@pytest.mark.parametrize("tau", ["cayley", "exp"])
def test_kelvin_noether_round_off_every_order(tau, order):
    system = vj.models.UnderwaterVehicle()
    sol = vj.simulate(system, system.initial_state(), 0.05, 1000, tau=tau, order=order)
    I = np.asarray(sol.kelvin_noether)
    assert np.max(np.abs(I - I[0])) <= 1e-13 * np.max(np.asarray(sol.kelvin_noether_scale))
    assert float(jnp.max(vj.group_constraint_residual(system, sol.R))) <= 1e-12


def test_symmetric_scheme_is_reversible():
    """Order 2 forward N steps then back N steps with −h returns to the start (seed 000 spec §5).
    Run backwards by reversing the velocities of the final state (time-reversal symmetry of ℓ)."""
    system = vj.models.UnderwaterVehicle()
    x0 = system.initial_state()
    fwd = vj.simulate(system, x0, 0.01, 500, order=2)
    back_start = vj.State(g=fwd.R[-1], xi=-fwd.omega[-1], q=fwd.q[-1], qdot=-(fwd.R[-1] @ fwd.nu[-1]))
    back = vj.simulate(system, back_start, 0.01, 500, order=2)
    assert float(jnp.max(jnp.abs(back.q[-1] - x0.q))) <= 1e-11
    assert float(jnp.max(jnp.abs(back.R[-1] - x0.g))) <= 1e-12
