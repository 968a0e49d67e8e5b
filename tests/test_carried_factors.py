"""Newton's factors carried from step to step in the generated batched step: the members solve
each step to Newton's tolerance with chord steps on an earlier Jacobian, so every member still
equals its own ``vj.simulate`` run to round-off, alone or among other members, its gradients
are the implicit-function ones, and a member whose chord steps fail takes the fallback
iterations (a fresh Jacobian) and a refresh at the next step."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj
from vi_jax.engine import _generated_step
from vi_jax.engine._member_newton import MAX_PERIOD, next_periods
from newton_iterations import COMMON_PATH, assert_first_converged_iterations_match

EPS = np.finfo(np.float64).eps
N_MEMBERS = 5

# The vehicle at orders 2 and 4 carries its factors by default; the heavy top is forced to.
SCENES = {
    "vehicle, order 2": (vj.models.UnderwaterVehicle(), 2, 0.01, None),
    "vehicle, order 4 (factors per sub-step)": (vj.models.UnderwaterVehicle(), 4, 0.01, None),
    "heavy top, order 2 (forced)": (vj.models.HeavyTop(), 2, 0.005, True),
    # The README's System (ξ–ν cross term, advected parameter, additional dynamics): its factors
    # do not always last, so some members take the fallback and lower their ceiling.
    "user System, order 4": "user",
    # h = 0.01: a fresh Jacobian already needs the fallback in about 40% of the steps.
    "heavy top, order 2, large steps (forced)": (vj.models.HeavyTop(), 2, 0.01, True),
}


def _states(x0, n, seed):
    rng = np.random.default_rng(seed)
    return vj.vary(x0, xi=np.asarray(x0.xi) + 0.1 * rng.normal(size=(n, 3)))


@pytest.fixture
def carry_factors(monkeypatch, fresh_programs):
    """Sets ``CARRY_FACTORS``; it is read at trace time, so compiled programs are dropped on each
    switch and after the test (no other test may reuse a program traced with it forced)."""

    def switch(value):
        monkeypatch.setattr(_generated_step, "CARRY_FACTORS", value)
        fresh_programs()

    return switch


def test_factors_are_carried_where_the_jacobian_costs_most():
    """The default carries the factors of the vehicle at order 2 (its residual's Jacobian costs
    about 5 residuals), not of the rigid body (about 2)."""
    costs = {}
    for name, system, order in (("vehicle", vj.models.UnderwaterVehicle(), 2), ("rigid body", vj.models.RigidBody(), 2)):
        states = _states(system.initial_state(), N_MEMBERS, 0)
        residual, with_jacobian = _generated_step.scene_operations(system, states, 0.01, "cayley", order)
        costs[name] = with_jacobian / residual
    assert costs["vehicle"] >= _generated_step.CARRY_COST > costs["rigid body"] > 1


def test_periods_grow_only_on_factors_that_last():
    """A step on older factors doubles the period (up to the ceiling) when its chord steps
    converged early and halves it when they did not; a step with a fresh Jacobian keeps it; the
    fallback halves it and makes that the ceiling (period 1: a fresh Jacobian every step)."""
    period = jnp.asarray([2, 4, 8, 8, 4, 8, 2])
    ceiling = jnp.asarray([MAX_PERIOD, MAX_PERIOD, 8, MAX_PERIOD, MAX_PERIOD, MAX_PERIOD, 8])
    refreshed = jnp.asarray([False, False, False, False, False, True, False])
    early = jnp.asarray([True, True, True, False, False, True, False])
    fell_back = jnp.asarray([False, False, False, False, True, False, True])
    period, ceiling = next_periods(period, ceiling, refreshed, early, fell_back)
    np.testing.assert_array_equal(period, [4, 8, 8, 4, 2, 8, 1])
    np.testing.assert_array_equal(ceiling, [MAX_PERIOD, MAX_PERIOD, 8, MAX_PERIOD, 2, MAX_PERIOD, 1])


@pytest.mark.parametrize("name", list(SCENES))
def test_members_equal_simulate_and_do_not_depend_on_each_other(name, carry_factors):
    """Every member equals its own ``vj.simulate`` run (each step stops at an iterate within
    Newton's tolerance 64ε: a random walk of √n such steps, with a factor 4 for its tail);
    a member's refresh schedule is its own: with the other members of its chunk changed (their
    Jacobians then fall on other steps), the first member's run is bitwise the same (not so if
    a Jacobian taken for one member were given to all)."""
    if SCENES[name] == "user":
        from test_generated_step import _user_system

        (system, x0), order, h, forced = _user_system(), 4, 0.01, None
    else:
        system, order, h, forced = SCENES[name]
        x0 = system.initial_state()
    carry_factors(forced)
    n_steps, save_every = 200, 8
    states = _states(x0, N_MEMBERS, 1)
    sol = vj.ensemble(system, states, h, n_steps, order=order, save_every=save_every, method="batched")
    rtol = 4 * 64 * EPS * np.sqrt(n_steps)
    for k in (0, N_MEMBERS - 1):
        ref = vj.simulate(system, jax.tree.map(lambda x: x[k], states), h, n_steps, order=order, save_every=save_every)
        for field in ("g", "xi", "M", "energy", "kelvin_noether"):
            ours, theirs = np.asarray(getattr(sol, field)[k]), np.asarray(getattr(ref, field))
            assert np.max(np.abs(ours - theirs)) <= rtol * max(np.max(np.abs(theirs)), 1.0), (field, np.max(np.abs(ours - theirs)))
    assert np.all(np.asarray(sol.result) == 0)
    assert np.max(np.asarray(sol.newton_residual)) <= 64 * EPS
    fast = vj.vary(x0, xi=3 * np.asarray(states.xi))  # turning faster: their factors age sooner
    others = jax.tree.map(lambda x, y: x.at[1:].set(y[1:]), states, fast)
    other = vj.ensemble(system, others, h, n_steps, order=order, save_every=save_every, method="batched")
    for field in ("g", "xi", "M", "newton_iterations"):
        np.testing.assert_array_equal(np.asarray(getattr(other, field)[0]), np.asarray(getattr(sol, field)[0]))


def test_carried_factors_skip_jacobians_and_keep_the_solution(carry_factors):
    """Against a fresh Jacobian every step, on the vehicle at order 2: no fallback (one Newton
    or chord step and at most two chord steps every step), the same iterations (but where a
    residual lies within round-off of the tolerance) and the same states to round-off, so the
    carried factors converge as fast as fresh ones here."""
    system = vj.models.UnderwaterVehicle()
    states = _states(system.initial_state(), N_MEMBERS, 2)
    runs = {}
    for forced in (False, True):
        carry_factors(forced)
        runs[forced] = vj.ensemble(system, states, 0.01, 300, order=2, save_every=10, method="batched")
    carried, fresh = (np.asarray(runs[c].newton_iterations)[:, 1:] for c in (True, False))
    assert np.all(carried <= COMMON_PATH) and np.all(fresh <= COMMON_PATH)
    assert_first_converged_iterations_match(carried, fresh)  # the vehicle's chord steps are checked
    ours, theirs = np.asarray(runs[True].g), np.asarray(runs[False].g)
    assert np.max(np.abs(ours - theirs)) <= 4 * 64 * EPS * np.sqrt(300)


def test_gradients_through_carried_factors_are_implicit(carry_factors):
    """Reverse mode with carried factors equals reverse mode with a fresh Jacobian every step
    (the factors only choose the iterates; the gradient is the implicit-function one)."""
    system = vj.models.HeavyTop()
    states = _states(system.initial_state(), 3, 3)
    masses = 1.0 + 0.1 * np.arange(3)

    def loss(masses):
        sol = vj.ensemble(vj.vary(system, mass=masses), states, 0.005, 60, order=2, save_every=20, system_axes=0, method="batched")
        return jnp.sum(sol.g[:, -1] ** 2) + jnp.sum(sol.xi[:, -1])

    grads = {}
    for forced in (False, True):
        carry_factors(forced)
        grads[forced] = np.asarray(jax.grad(loss)(masses))
    assert np.all(np.isfinite(grads[True])) and np.max(np.abs(grads[True])) > 0
    np.testing.assert_allclose(grads[True], grads[False], rtol=1e-9, atol=1e-12)
