"""Newton's chord steps checked in the generated batched step (``newton_members``'
``checked_chords``): each member stops at its first converged iterate, counted as a plain
per-member chord iteration counts it, its result independent of the other members; the scenes
whose residual costs most are checked by default."""

import jax
import jax.numpy as jnp
import numpy as np

import vi_jax as vj
from vi_jax.engine import _generated_step
from vi_jax.engine._member_newton import lu, newton_members

RTOL = 1e-12


def _residual(z, c):
    """Per member: z³ + z − c = 0 (one unknown), scaled by the terms that cancel."""
    (x,) = z
    return (x**3 + x - c,), jnp.abs(x**3) + jnp.abs(x) + jnp.abs(c)


def _first_converged_count(x, c, max_iterations=20, chord_iterations=2, slope=None):
    """A plain float loop: one Newton step (a chord step on ``slope``, a derivative carried from
    elsewhere, if given), chord steps on that derivative while not converged (the fallback's
    first step too: it still holds those factors), then Newton steps with the derivative at each
    new iterate; the iterations up to the first converged iterate."""
    slope = 3 * x**2 + 1 if slope is None else slope
    for i in range(1, max_iterations + 1):
        x = x - (x**3 + x - c) / slope
        if abs(x**3 + x - c) <= RTOL * (abs(x**3) + abs(x) + abs(c)):
            return i
        if i >= 2 + chord_iterations:
            slope = 3 * x**2 + 1
    return max_iterations


def test_each_member_stops_at_its_first_converged_iterate():
    """Members from a good and from poor first guesses in one batch: the iteration counts equal a
    per-member loop's, the roots solve the equation, and a member's root and count are the same
    bits alone as among the others."""
    c = jnp.asarray([2.0, 2.0 + 1e-9, 10.0, -3.0, 0.5])
    guess = jnp.asarray([1.0, 1.0, 1.5, -1.0, 0.45])
    ident = lambda tree: tree  # noqa: E731  (a boundary that marks nothing)

    def solve(c, guess):
        return newton_members(lambda z: _residual(z, c), (guess,), rtol=RTOL, max_iterations=20, checked_chords=ident)

    (x,), (iterations, rel, result) = solve(c, guess)
    expected = [_first_converged_count(float(g), float(ci)) for g, ci in zip(guess, c)]
    np.testing.assert_array_equal(np.asarray(iterations), expected)
    assert len(set(expected)) > 1  # the members really stop at different iterates
    assert np.all(np.asarray(result) == 0) and np.all(np.asarray(rel) <= RTOL)
    np.testing.assert_allclose(np.asarray(x**3 + x), np.asarray(c), rtol=4 * RTOL)
    for k in range(len(c)):
        (alone,), (alone_iterations, _, _) = solve(c[k : k + 1], guess[k : k + 1])
        assert float(alone[0]) == float(x[k]) and int(alone_iterations[0]) == int(iterations[k]), k


def test_rolled_iterations_with_carried_factors_are_the_unrolled_ones():
    """With carried factors, the full iterations' program rolls Newton's iterations into one loop
    (``rolled=True``): members that refresh their factors and members that keep a carried
    derivative (some close to theirs, some far enough off to need the full iterations) take the
    plain loop's iteration counts, and the iterates, counts, the factors carried on, and the
    early and fallback flags equal the unrolled steps' (the roots to round-off: XLA may contract
    the two programs' arithmetic differently)."""
    # Near the root x = 1 of x³ + x = 2 (derivative 4) with carried derivatives close to 4: the
    # chord steps converge at the 2nd, 3rd or 4th iterate, early (before the last chord step)
    # or not; the sixth member's derivative is far off.
    c = jnp.asarray([2.0, 2.0, 10.0, -3.0, 0.5, 10.0, 2.0, 2.0, 2.0, 2.0])
    guess = jnp.asarray([1.0, 1.0, 1.9, -1.2, 0.45, 2.0, 1.00001, 1.00001, 1.0001, 1.01])
    carried = jnp.asarray([4.0, 9.0, 11.0, 5.3, 1.6, 40.0, 4.0, 4.01, 4.01, 4.0])
    refresh = jnp.asarray([True, False, False, True, False, False, False, False, False, False])
    ident = lambda tree: tree  # noqa: E731

    def solve(rolled):
        return newton_members(lambda z: _residual(z, c), (guess,), rtol=RTOL, max_iterations=20, checked_chords=ident,
                              factors=lu([[carried]]), refresh=refresh, rolled=rolled)

    (x, stats, (factors, early, fell_back)), (x_u, stats_u, (factors_u, early_u, fell_back_u)) = solve(True), solve(False)
    expected = [_first_converged_count(float(g), float(ci), slope=None if r else float(s))
                for g, ci, r, s in zip(guess, c, refresh, carried)]
    np.testing.assert_array_equal(np.asarray(stats[0]), expected)
    assert {1, 2, 3, 4} <= set(expected) and max(expected) > 4
    np.testing.assert_array_equal(np.asarray(stats[0]), np.asarray(stats_u[0]))
    np.testing.assert_array_equal(np.asarray(stats[2]), np.asarray(stats_u[2]))
    np.testing.assert_array_equal(np.asarray(early), np.asarray(early_u))
    np.testing.assert_array_equal(np.asarray(fell_back), np.asarray(fell_back_u))
    assert len(set(zip(np.asarray(early).tolist(), np.asarray(fell_back).tolist()))) == 4  # every combination
    np.testing.assert_allclose(np.asarray(x[0]), np.asarray(x_u[0]), rtol=8 * np.finfo(float).eps)
    for a, b in zip(jax.tree.leaves(factors), jax.tree.leaves(factors_u)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=8 * np.finfo(float).eps)


def test_unchecked_chord_steps_all_run():
    """Without checks every member takes the Newton step and both chord steps (the accelerator
    plan's step), then the fallback where needed: at least three iterations each."""
    c = jnp.asarray([2.0, 10.0])
    _, (iterations, _, result) = newton_members(lambda z: _residual(z, c), (jnp.asarray([1.0, 1.5]),), rtol=RTOL, max_iterations=20)
    assert np.all(np.asarray(iterations) >= 3) and np.all(np.asarray(result) == 0)


def test_chords_are_checked_where_the_residual_costs_most():
    """The default checks the vehicle's chord steps (a residual of over 200 operations per
    member at orders 1 and 2), not the rigid body's (under 160)."""
    costs = {}
    for name, system, order in (("vehicle", vj.models.UnderwaterVehicle(), 1), ("vehicle 2", vj.models.UnderwaterVehicle(), 2),
                                ("rigid body", vj.models.RigidBody(), 2)):
        x0 = system.initial_state()
        states = vj.vary(x0, xi=jnp.stack([x0.xi, 1.1 * x0.xi]))
        costs[name] = _generated_step.scene_operations(system, states, 0.01, "cayley", order)[0]
    assert min(costs["vehicle"], costs["vehicle 2"]) >= _generated_step.CHECK_COST > costs["rigid body"] > 0


def test_a_vehicle_member_is_the_same_among_other_members():
    """The vehicle (checked by default) at order 1: member 0's trajectory and iteration counts
    are the same bits whichever members share its chunk (others turning three times faster
    need more iterations per step)."""
    system = vj.models.UnderwaterVehicle()
    x0 = system.initial_state()
    rng = np.random.default_rng(3)
    xi = np.asarray(x0.xi) + 0.1 * rng.normal(size=(6, 3))
    runs = []
    for scale in (1.0, 3.0):
        others = xi.copy()
        others[1:] *= scale
        runs.append(vj.ensemble(system, vj.vary(x0, xi=others), 0.02, 200, save_every=10, method="batched"))
    assert np.mean(np.asarray(runs[1].newton_iterations)[1:]) > np.mean(np.asarray(runs[0].newton_iterations)[1:])
    for field in ("g", "xi", "q", "nu", "newton_iterations"):
        np.testing.assert_array_equal(np.asarray(getattr(runs[0], field)[0]), np.asarray(getattr(runs[1], field)[0]))
