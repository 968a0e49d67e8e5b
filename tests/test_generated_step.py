"""The generated batched step (``vj.ensemble``'s fast path for any scene): the component-array
interpreter against plain evaluation, the generated step free of small dense algebra, and
ensembles of several scenes (groups, τ, orders, a user ``System`` with advected parameters and
additional dynamics) equal to ``vj.simulate`` member by member, with implicit gradients."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj
from vi_jax.engine._components import components, componentwise, stacked
from vi_jax.lie import SO3, SOn, LinearAction
from newton_iterations import COMMON_PATH, assert_first_converged_iterations_match, assert_rolled_iterations_match, chords_checked
from test_one_kernel import one_kernel_calls

EPS = np.finfo(np.float64).eps
N_MEMBERS = 5


def _probe(x, w, A, s):
    """Per member: every structural rule and a primitive without one (sort: the fallback)."""
    B = jnp.einsum("ij,jk->ik", A, A.T) + jnp.outer(x, w)  # dot_general, transpose
    batched = jnp.einsum("bij,bj->bi", jnp.stack([A, B]), jnp.stack([x, w]))  # batch dimensions
    y = jnp.concatenate([x[1:], jnp.pad(w, (1, 0))[:1]]) ** 3  # slice, pad, concatenate, integer_pow
    z = jnp.where(x > 0.1, jnp.sin(x) / x, jnp.cos(w)) * s  # select_n, shared scalar
    reduced = jnp.max(jnp.abs(B), axis=0) + jnp.sum(B.reshape(-1)[::2]) - jnp.min(batched)
    return jnp.linalg.norm(y) * z + reduced + jnp.sort(x) + batched[1, ::-1], jnp.trace(B)


def test_components_equal_plain_evaluation():
    """The interpreter's rules (and its fallback) against ``jax.vmap`` of the same function,
    per-member and shared arguments mixed: equal to a few ε (sums are associated differently)."""
    rng = np.random.default_rng(0)
    x, w = rng.normal(size=(N_MEMBERS, 3)), rng.normal(size=(N_MEMBERS, 3))
    A, s = rng.normal(size=(3, 3)), jnp.asarray(0.7)
    expected = jax.vmap(_probe, in_axes=(0, 0, None, None))(x, w, A, s)
    out = componentwise(_probe, N_MEMBERS)(components(x, True), components(w, True), components(A, False), components(s, False))
    for ours, theirs in zip(out, expected):
        ours = stacked(ours, N_MEMBERS)
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=64 * EPS * float(np.max(np.abs(theirs))))


def test_constant_zeros_are_folded_away():
    """A Jacobian by forward mode on components: the products with the basis' zeros vanish at
    trace time, so a diagonal quadratic's Hessian-vector work is one multiply per entry."""

    def hessian(x, d):
        return jax.jacfwd(jax.grad(lambda x: 0.5 * jnp.sum(d * x**2) + x[0] * x[1]))(x)

    fn = componentwise(hessian, N_MEMBERS)
    jaxpr = jax.make_jaxpr(lambda x, d: [jnp.asarray(e) for e in fn(components(x, True), components(d, False)).reshape(-1)])(
        jnp.ones((N_MEMBERS, 3)), jnp.ones(3)
    )
    per_member = [e for e in jaxpr.eqns if e.primitive.name == "mul" and e.outvars[0].aval.shape == (N_MEMBERS,)]
    assert len(per_member) == 0  # ℓ's Hessian does not depend on x: nothing is computed per member
    values = np.asarray([stacked(np.asarray(v), N_MEMBERS) for v in fn(components(np.ones((N_MEMBERS, 3)), True), components(np.arange(3.0), False)).reshape(-1)])
    np.testing.assert_array_equal(values[:, 0], [0, 1, 0, 1, 1, 0, 0, 0, 2])


def test_shared_values_pass_the_boundary_once():
    """A value marked ``shared`` reaches the caller's boundary once per component, its forward-
    mode tangents do not (a Jacobian reads each column once), the values are those of the
    unmarked function, and outside the generated step the mark is not traced at all."""
    from vi_jax._shared_values import shared

    def value_and_jacobian(x, A):
        def f(x):
            y = shared(jnp.sin(A @ x))  # read by every output component
            return y * y[0] + x

        return f(x), jax.jacfwd(f)(x)

    rng = np.random.default_rng(1)
    x, A = rng.normal(size=(N_MEMBERS, 3)), rng.normal(size=(3, 3))
    seen = []

    def boundary(values):
        seen.append(len(values))
        return [v + 0.0 for v in values]

    fn = componentwise(value_and_jacobian, N_MEMBERS)
    args = (components(x, True), components(A, False))
    marked, unmarked = fn(*args, boundary=boundary), fn(*args)
    assert seen == [3, 3]  # y's three components, in f(x) and in jacfwd's primal; no tangent
    expected = jax.vmap(value_and_jacobian, in_axes=(0, None))(x, A)
    for ours, plain, theirs in zip(marked, unmarked, expected):
        np.testing.assert_allclose(stacked(ours, N_MEMBERS), theirs, rtol=0, atol=64 * EPS * float(np.max(np.abs(theirs))))
        np.testing.assert_array_equal(stacked(ours, N_MEMBERS), stacked(plain, N_MEMBERS))
    system, x0, tau, order, h = _scene("heavy top, Cayley, order 2")
    jaxpr = str(jax.make_jaxpr(lambda x0: vj.simulate(system, x0, h, 3, tau=tau, order=order, throw=False).g)(x0))
    assert "optimization_barrier" not in jaxpr


def _user_system():
    """The README's ``vj.System``: SO(3), advected parameter and additional dynamics, a ξ–ν cross
    term (not separable, not a model class)."""
    J, M = np.diag([2.0, 3.0, 4.0]), np.diag([5.0, 6.0, 7.0])
    lagrangian = lambda xi, n, nu, a, p: 0.5 * xi @ J @ xi + 0.5 * nu @ M @ nu + 0.4 * xi @ nu - p * n @ a  # noqa: E731
    system = vj.System(SO3(), lagrangian, jnp.asarray(9.81), advected=(LinearAction(SO3()), np.eye(3)[2]), additional=LinearAction(SO3()))
    return system, vj.State(jnp.eye(3), jnp.array([0.3, -0.2, 0.5]), jnp.zeros(3), jnp.array([0.1, 0.0, -0.2]))


SCENES = {
    "heavy top, Cayley, order 2": (vj.models.HeavyTop(), "cayley", 2, 0.005),
    "rigid body, exp, order 1": (vj.models.RigidBody(), "exp", 1, 0.01),
    "heavy top on SO(4), order 1": (vj.models.HeavyTop(group=SOn(4)), "cayley", 1, 0.005),
    "user System, order 4": (*_user_system(), "cayley", 4, 0.01),
}


def _scene(name, scenes=SCENES):
    entry = scenes[name]
    if len(entry) == 5:
        system, x0, tau, order, h = entry
    else:
        system, tau, order, h = entry
        x0 = system.initial_state()
    return system, x0, tau, order, h


def _states(x0, seed):
    rng = np.random.default_rng(seed)
    return vj.vary(x0, xi=np.asarray(x0.xi) + 0.1 * rng.normal(size=(N_MEMBERS,) + np.shape(x0.xi)))


@pytest.mark.parametrize("name", list(SCENES))
def test_generated_step_equals_simulate_member_by_member(name, monkeypatch, fresh_programs):
    """Every member equals its own ``vj.simulate`` run: the same scheme and Newton iteration on
    component arrays, so each step may stop at an iterate that differs within Newton's
    tolerance 64ε (a random walk of √n such steps, with a factor 4 for its tail). A fresh
    Jacobian every step, as ``vj.simulate`` takes (carried factors: tests/test_carried_factors.py);
    the concrete run's rolled iterations stop at the first converged iterate
    (:func:`assert_rolled_iterations_match`), as the ensemble's do where its chord steps are
    checked (:func:`assert_first_converged_iterations_match`)."""
    from vi_jax.engine import _generated_step

    monkeypatch.setattr(_generated_step, "CARRY_FACTORS", False)
    fresh_programs()  # the switch is read at trace time
    system, x0, tau, order, h = _scene(name)
    n_steps, save_every = 120, 8
    states = _states(x0, 1)
    match_iterations = assert_first_converged_iterations_match if chords_checked(system, states, h, tau, order) else assert_rolled_iterations_match
    sol = vj.ensemble(system, states, h, n_steps, tau=tau, order=order, save_every=save_every, method="batched")
    rtol = 4 * 64 * EPS * np.sqrt(n_steps)
    for k in (0, N_MEMBERS - 1):
        ref = vj.simulate(system, jax.tree.map(lambda x: x[k], states), h, n_steps, tau=tau, order=order, save_every=save_every)
        for field in ("g", "xi", "M", "energy", "kelvin_noether", "result"):
            ours, theirs = np.asarray(getattr(sol, field)[k]), np.asarray(getattr(ref, field))
            assert ours.shape == theirs.shape, field
            assert np.max(np.abs(ours - theirs)) <= rtol * max(np.max(np.abs(theirs)), 1.0), (field, np.max(np.abs(ours - theirs)))
        match_iterations(ref.newton_iterations, sol.newton_iterations[k])
    kn = np.asarray(sol.kelvin_noether).reshape(N_MEMBERS, n_steps // save_every + 1, -1)
    scale = np.asarray(sol.kelvin_noether_scale).reshape(N_MEMBERS, -1).max(axis=1)
    assert np.all(np.max(np.abs(kn - kn[:, :1]), axis=(1, 2)) <= 1e-12 * scale)


def test_generated_step_has_no_small_dense_algebra():
    """The generated step of an order-2 heavy top contains no ``dot_general``: every product
    is elementwise over the members (with Newton's factors carried from step to step or not)."""
    from vi_jax.discrete import composition_coefficients
    from vi_jax.engine._generated_step import _start, make_step
    from vi_jax.lie import difference_map

    system, x0, tau, order, h = _scene("heavy top, Cayley, order 2")
    states = _states(x0, 2)
    axes = (jax.tree.map(lambda _: None, system), jax.tree.map(lambda _: 0, states))
    rule, _ = composition_coefficients(order)

    params, static, _, layout, carry = _start(system, states, axes, jnp.float64, N_MEMBERS)

    def primitives(max_iterations, carry_factors):
        step = make_step(static, params, difference_map(tau), rule, 1e-14, max_iterations, N_MEMBERS, layout, True, carry_factors)
        names = set()

        def visit(jaxpr):
            for eqn in jaxpr.eqns:
                names.add(eqn.primitive.name)
                for sub in jax.extend.core.jaxprs_in_params(eqn.params):
                    visit(sub)

        visit(jax.make_jaxpr(step)((carry, step.start(carry)), jnp.asarray(h)).jaxpr)
        return names

    for carry_factors in (False, True):
        names = primitives(20, carry_factors)
        assert "mul" in names and "dot_general" not in names and "while" in names
        # At most one Newton and two chord steps: the fallback iterations could never run, and
        # none is compiled (as in vj.simulate's Newton).
        assert "while" not in primitives(3, carry_factors)


def test_generated_step_gradients_equal_the_vmap_path():
    """Reverse mode through the generated step (implicit-function gradients, checkpointed) equals
    reverse mode through the ``vmap`` path, per-member parameters (the same scheme: to Newton's
    tolerance, amplified by the 120 steps)."""
    system, x0, tau, order, h = _scene("heavy top, Cayley, order 2")
    states = _states(x0, 3)
    masses = 1.0 + 0.1 * np.arange(N_MEMBERS)

    def loss(masses, method):
        sol = vj.ensemble(vj.vary(system, mass=masses), states, h, 120, order=order, save_every=40, system_axes=0, method=method)
        return jnp.sum(sol.g[:, -1, 2] ** 2) + jnp.sum(sol.M[:, -1] ** 2)

    ours, theirs = (np.asarray(jax.jit(jax.grad(loss), static_argnums=1)(masses, m)) for m in ("batched", "vmap"))
    assert np.all(np.abs(theirs) > 0)
    np.testing.assert_allclose(ours, theirs, rtol=1e-9)


def test_looped_and_traced_generated_runs_agree():
    """Concrete inputs take traced step counts (one program per capacity); under ``jit`` the
    counts are static: the same steps, equal to round-off. At h = 0.005 no member needs Newton's
    full iterations, so the concrete call compiles only its program without them (at h = 0.01 it
    compiled both: 1.7x this test's time; the full program's members against ``vj.simulate``:
    test_generated_step_equals_simulate_member_by_member)."""
    system, x0, tau, order, _ = _scene("user System, order 4")
    states = _states(x0, 4)
    run = lambda s: vj.ensemble(system, s, 0.005, 60, order=order, save_every=4, method="batched")  # noqa: E731
    looped, traced = run(states), eqx.filter_jit(run)(states)
    assert np.max(np.asarray(looped.newton_iterations)) <= 3
    for a, b in zip(jax.tree.leaves(looped), jax.tree.leaves(traced)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-14)


def test_newton_starts_from_the_extrapolated_velocity(monkeypatch, fresh_programs):
    """A single-stage step starts Newton from 2ξ_k − ξ_{k−1} (error O(h²)) instead of ξ_k (O(h)):
    the heavy top at h = 0.01 (order 2) needs Newton's fallback iterations (more than one Newton
    and two chord steps) in about 40% of its member-steps from ξ_k and in almost none from the
    extrapolation, in the generated step as in ``vj.simulate``; the members equal ``vj.simulate``
    (the same solutions, within Newton's tolerance, from either guess)."""
    from vi_jax.engine import _generated_step

    model = vj.models.HeavyTop()
    states = _states(model.initial_state(), 2)
    n_steps, h = 200, 0.01
    fallback, runs = {}, {}
    for extrapolated in (False, True):
        monkeypatch.setattr(_generated_step, "PREDICT", extrapolated)
        fresh_programs()  # the switch is read at trace time
        runs[extrapolated] = vj.ensemble(model, states, h, n_steps, order=2, method="batched")
        fallback[extrapolated] = np.mean(np.asarray(runs[extrapolated].newton_iterations)[:, 1:] > 3)
    assert fallback[False] >= 0.2 and fallback[True] <= fallback[False] / 20, fallback
    ref = vj.simulate(model, jax.tree.map(lambda x: x[0], states), h, n_steps, order=2)
    assert np.mean(np.asarray(ref.newton_iterations)[1:] > 3) <= fallback[False] / 20
    rtol = 4 * 64 * EPS * np.sqrt(n_steps)
    for sol in runs.values():
        assert np.max(np.abs(np.asarray(sol.g[0]) - np.asarray(ref.g))) <= rtol


def test_accelerator_plan_equals_the_cpu_plan(monkeypatch):
    """The accelerator plan (every member in every kernel, no fusion boundaries) against the CPU
    plan (chunks of 64 members, conditionals as fusion boundaries), both run here: the same
    steps, equal to round-off (XLA may contract the two programs differently: a few ε per step
    over 120 steps, far below 1e-12)."""
    from vi_jax.engine import _ensemble

    system, x0, tau, order, h = _scene("heavy top, Cayley, order 2")
    states = _states(x0, 5)
    plans = {}
    for platform in ("cpu", "gpu"):
        monkeypatch.setattr(_ensemble, "target_platform", lambda mesh=None, p=platform: p)
        plans[platform] = vj.ensemble(system, states, h, 120, order=order, save_every=40, method="batched")
    gpu, cpu = (eqx.tree_at(lambda s: s.newton_iterations, plans[p], None) for p in ("gpu", "cpu"))
    for a, b in zip(jax.tree.leaves(gpu), jax.tree.leaves(cpu)):
        a, b = np.asarray(a), np.asarray(b)
        assert np.max(np.abs(a - b)) <= 1e-12 * max(np.max(np.abs(b)), 1.0)
    # The CPU plan checks this scene's chord steps; the accelerator plan runs them all.
    assert np.all(np.asarray(plans["cpu"].newton_iterations) <= np.asarray(plans["gpu"].newton_iterations))
    assert np.all(np.asarray(plans["gpu"].newton_iterations)[:, 1:] >= COMMON_PATH)


def _accelerator_plan_runs(monkeypatch, fresh_programs, run, speculative):
    """``run()`` on the accelerator plan, with the speculative step or with Newton's fallback
    inside the step, traced afresh."""
    from vi_jax.engine import _ensemble, _generated_step

    monkeypatch.setattr(_ensemble, "target_platform", lambda mesh=None: "gpu")
    monkeypatch.setattr(_generated_step, "SPECULATIVE", speculative)
    fresh_programs()  # the switches are read at trace time
    return run()


def _hard_heavy_top_states():
    """Heavy top members at h = 0.02 with velocities 0.5·N(0, 1) off: a quarter of the
    member-steps need Newton's fallback iterations."""
    system = vj.models.HeavyTop()
    x0 = system.initial_state()
    return system, vj.vary(x0, xi=np.asarray(x0.xi) + 0.5 * np.random.default_rng(0).normal(size=(16, 3)))


def test_speculative_accelerator_step_equals_the_step_with_its_fallback(monkeypatch, fresh_programs):
    """The accelerator plan's speculative step (every member without Newton's fallback, then
    the whole step again where one member needs it; two steps per loop iteration, 9 steps per
    node: an odd remainder) against the step with the fallback inside, under ``jit``: steps that
    fell back and steps that did not, equal to Newton's tolerance 64ε per step (a member may stop
    one iteration apart at the tolerance's edge)."""
    system, states = _hard_heavy_top_states()
    n_steps = 180
    run = jax.jit(lambda s: vj.ensemble(system, s, 0.02, n_steps, save_every=9, throw=False))
    ours, theirs = (_accelerator_plan_runs(monkeypatch, fresh_programs, lambda: run(states), spec) for spec in (True, False))
    iterations = np.asarray(theirs.newton_iterations)[:, 1:]
    assert 0.05 < np.mean(iterations > 3) < 0.95  # nodes with and without the fallback
    assert np.all(np.asarray(ours.result) == 0) and np.all(np.asarray(theirs.result) == 0)
    assert np.max(np.abs(np.asarray(ours.newton_iterations)[:, 1:] - iterations)) <= 1
    rtol = 4 * 64 * EPS * np.sqrt(n_steps)
    for field in ("g", "xi", "M", "energy"):
        a, b = np.asarray(getattr(ours, field)), np.asarray(getattr(theirs, field))
        assert np.max(np.abs(a - b)) <= rtol * max(np.max(np.abs(b)), 1.0), field


def test_speculative_accelerator_step_differentiates_as_the_step_with_its_fallback(monkeypatch, fresh_programs):
    """Reverse mode through the speculative step (a loop of traced length, which has no reverse
    mode of its own) is reverse mode through the step with the fallback inside, for the scene's
    parameters and h alike (one program each way); and it matches central differences in h."""
    system, states = _hard_heavy_top_states()

    def loss(args):
        system, h = args
        sol = vj.ensemble(system, states, h, 40, save_every=20, throw=False)
        return jnp.sum(sol.xi[:, -1] ** 2) + jnp.sum(sol.g[:, -1])

    grad = eqx.filter_jit(eqx.filter_grad(loss))  # h an array: differentiated with the parameters
    ours, theirs = (_accelerator_plan_runs(monkeypatch, fresh_programs, lambda: grad((system, jnp.asarray(0.02))), spec) for spec in (True, False))
    for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(theirs)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12)
    eps = 1e-6
    central = (loss((system, 0.02 + eps)) - loss((system, 0.02 - eps))) / (2 * eps)
    np.testing.assert_allclose(ours[1], central, rtol=1e-6)


def test_only_the_cpu_plan_hides_the_inputs_behind_a_barrier(monkeypatch):
    """Under a caller's trace the CPU plan puts the scene and h behind an optimisation barrier
    (its fusion boundaries would fold away on constants) and its member loops in one kernel
    region; the accelerator plan has no boundaries to keep, and there the barrier only cost
    constant folding: its program holds neither."""
    from vi_jax.engine import _ensemble

    system, x0, tau, order, h = _scene("heavy top, Cayley, order 2")
    states = _states(x0, 5)
    for platform, barrier in (("cpu", True), ("gpu", False)):
        monkeypatch.setattr(_ensemble, "target_platform", lambda mesh=None, p=platform: p)
        run = lambda s: vj.ensemble(system, s, h, 3, order=order, method="batched", throw=False).g  # noqa: E731
        jaxpr = str(jax.make_jaxpr(run)(states))
        assert ("optimization_barrier" in jaxpr) == ("vi_jax_one_kernel" in jaxpr) == barrier


def test_members_run_in_balanced_chunks(monkeypatch, fresh_programs):
    """On the CPU plan ``CHUNK`` + 9 members run as two equal chunks (the second padded): the
    members on both sides of the seam and the last one equal their own ``vj.simulate`` runs."""
    from vi_jax.engine import _ensemble, _member_groups
    from vi_jax.engine._member_split import CHUNK

    seen, sizes = [], []
    real = _ensemble.in_chunks

    def in_chunks(dynamic, static, axes, n_members, chunk, kernel):
        seen.append(chunk)

        def sized(system, x0, n):
            sizes.append(n)
            return kernel(system, x0, n)

        return real(dynamic, static, axes, n_members, chunk, sized)

    monkeypatch.setattr(_ensemble, "in_chunks", in_chunks)
    monkeypatch.setattr(_member_groups, "cores", lambda: 1)  # one program for all members, on any machine
    fresh_programs()  # in_chunks is read at trace time
    system, x0, tau, order, h = _scene("rigid body, exp, order 1")
    n, n_steps, save_every = CHUNK + 9, 40, 8
    states = vj.vary(x0, xi=np.asarray(x0.xi) + 0.1 * np.random.default_rng(3).normal(size=(n, 3)))
    sol = vj.ensemble(system, states, h, n_steps, tau=tau, order=order, save_every=save_every, method="batched")
    half = -(-n // 16) * 8  # two chunks of whole SIMD lanes (8)
    assert seen == [CHUNK] and sizes == [half]
    for k in (0, half - 1, half, n - 1):
        ref = vj.simulate(system, jax.tree.map(lambda x: x[k], states), h, n_steps, tau=tau, order=order, save_every=save_every)
        for field in ("g", "xi", "M"):
            ours, theirs = np.asarray(getattr(sol, field)[k]), np.asarray(getattr(ref, field))
            assert np.max(np.abs(ours - theirs)) <= 4 * 64 * EPS * np.sqrt(n_steps) * np.max(np.abs(theirs)), (k, field)


def test_unknowns_with_explicit_equations_are_solved_before_newton(monkeypatch, fresh_programs):
    """Rows of the Jacobian affine in the unknowns (coefficients shared by all members, or per
    member but independent of the unknowns: read from the Jacobian's jaxpr) and zero outside as
    many unknowns are solved first, exactly; Newton runs on the rest. The vehicle at order 1:
    P_k = ℓ_ν − hℓ_n
    (seed 000 eq. 74) makes ν explicit, so Newton sees ω alone (3 unknowns of 6), with shared
    and with per-member masses, and the members still equal their own ``vj.simulate`` runs (a
    6×6 Newton there); at order 2 the rule couples ξ and ν: no block."""
    from vi_jax.discrete import composition_coefficients
    from vi_jax.engine import _generated_step, _member_newton
    from vi_jax.engine._member_newton import explicit_block
    from vi_jax.lie import difference_map

    member, shared = jnp.ones(N_MEMBERS), jnp.asarray(2.0)
    assert explicit_block([[member, member], [0.0, shared]]) == ([1], [1])
    assert explicit_block([[member, member], [shared, shared]]) is None  # ν's row reads ξ
    assert explicit_block([[member, 0.0], [member, member]]) is None

    sizes = []
    newton = _member_newton.newton_members

    def spy(fn, z0, **kwargs):
        sizes.append(len(z0))
        return newton(fn, z0, **kwargs)

    monkeypatch.setattr(_member_newton, "newton_members", spy)
    fresh_programs()  # traced afresh, through the spy
    system = vj.models.UnderwaterVehicle()
    states = _states(system.initial_state(), 4)
    masses = system.mass * (1 + 0.02 * np.arange(N_MEMBERS))
    n_steps = 40
    for systems, axes in ((system, None), (vj.vary(system, mass=masses), 0)):  # shared / per-member coefficients
        sizes.clear()
        sol = vj.ensemble(systems, states, 0.01, n_steps, save_every=8, system_axes=axes, method="batched")
        assert sizes and set(sizes) == {3}
        for k in (0, N_MEMBERS - 1):
            member = system if axes is None else jax.tree.map(lambda x: x[k], systems)
            ref = vj.simulate(member, jax.tree.map(lambda x: x[k], states), 0.01, n_steps, save_every=8)
            for field in ("g", "xi", "nu", "M", "P", "result"):
                ours, theirs = np.asarray(getattr(sol, field)[k]), np.asarray(getattr(ref, field))
                assert np.max(np.abs(ours - theirs)) <= 4 * 64 * EPS * np.sqrt(n_steps) * max(np.max(np.abs(theirs)), 1.0), field
            assert_first_converged_iterations_match(ref.newton_iterations, sol.newton_iterations[k])  # checked chord steps

    def block_of(order):  # traced only
        axes = (jax.tree.map(lambda _: None, system), jax.tree.map(lambda _: 0, states))
        params, static, _, layout, carry = _generated_step._start(system, states, axes, jnp.float64, N_MEMBERS)
        rule, _ = composition_coefficients(order)
        equations, _ = _generated_step._equations_of(static, params, difference_map("cayley"), rule, N_MEMBERS, layout, False)
        found = []

        def trace(z):
            found.append(explicit_block(equations(carry, jnp.asarray(0.01))[3](z)[2]))
            return z

        jax.make_jaxpr(trace)(carry[4])
        return found[0]

    assert block_of(1) == ([3, 4, 5], [3, 4, 5])
    assert block_of(2) is None


@pytest.mark.parametrize("name", ["user System, order 4", "rigid body, exp, order 1"])
def test_cpu_plan_loops_are_one_kernel(name, monkeypatch):
    """The CPU plan's member loops reach XLA as one call it compiles into a single kernel
    (``xla_cpu_small_call``), under a caller's ``jit`` and in the concrete call's program, for a
    user ``System`` as for a model (at order 1: the plan does not depend on it; the accelerator
    plan: the test above)."""
    from vi_jax.engine import _ensemble, _member_groups
    from vi_jax.lie import difference_map

    monkeypatch.setattr(_member_groups, "cores", lambda: 1)
    system, x0, tau, _, h = _scene(name)
    order, states = 1, _states(x0, 4)
    run = lambda s: vj.ensemble(system, s, h, 12, tau=tau, order=order, save_every=4, method="batched", throw=False).g  # noqa: E731
    assert one_kernel_calls(jax.jit(run).lower(states).compile()) == 1
    options = dict(n_members=N_MEMBERS, capacity=4, tau=difference_map(tau), order=order, rtol=1e-14, max_iterations=20,
                   batched="generated", chunk=_ensemble.CHUNK)
    dynamic, static = eqx.partition((system, states), eqx.is_array)
    axes = (jax.tree.map(lambda _: None, system), jax.tree.map(lambda _: 0, states))
    counts = (jnp.asarray(3, jnp.int32), jnp.asarray(4, jnp.int32))
    concrete = _ensemble._run_loop.lower(dynamic, static, axes, jnp.asarray(h), *counts, **options).compile().compiled
    assert one_kernel_calls(concrete) == 1


def test_fusion_boundaries_survive_a_jit_that_closes_over_the_scene():
    """Under a caller's ``jit`` that closes over the scene and h, XLA sees them as constants; the
    generated step's inputs pass an optimisation barrier, so its fusion boundaries (conditionals
    on h == h) stay in the optimised program, as when they are arguments."""
    system, x0, tau, order, h = _scene("rigid body, exp, order 1")
    states = _states(x0, 9)
    run = lambda m, s, h: vj.ensemble(m, s, h, 10, tau=tau, save_every=10, method="batched").g  # noqa: E731

    def conditionals(compiled):
        return compiled.as_text().count(" conditional(")

    closed = conditionals(jax.jit(lambda s: run(system, s, h)).lower(states).compile())
    passed = conditionals(jax.jit(run).lower(system, states, jnp.asarray(h)).compile())
    assert closed == passed > 0


def _quartic_top():
    """A free top whose kinetic energy is not quadratic (ℓ = ½ξᵀJξ + ¼κ|ξ|⁴): its inverse
    Legendre map is nonlinear, so Newton iterates."""
    J = jnp.asarray([2.0, 3.0, 4.0])
    system = vj.System(SO3(), lambda xi, n, nu, a, kappa: 0.5 * xi @ (J * xi) + 0.25 * kappa * (xi @ xi) ** 2, jnp.asarray(0.5))
    return system, vj.State(jnp.eye(3), jnp.array([0.9, -0.6, 1.2]), None, None), "cayley", 1, 0.01


NODE_SCENES = {**SCENES, "quartic kinetic energy": _quartic_top()}


def _node_problem(name):
    """A scene's saved nodes after 40 steps, moved off their velocities' root (a Newton guess)."""
    system, x0, tau, order, h = _scene(name, NODE_SCENES)
    sol = vj.simulate(system, x0, h, 40, tau=tau, order=order)
    states = vj.discrete.StepState(sol.g, sol.q, sol.M, sol.P, sol.xi if sol.nu is None else jnp.concatenate([sol.xi, sol.nu], -1))
    return system, jax.tree.map(lambda x: x + 0.01 * jnp.sin(jnp.arange(x.size, dtype=x.dtype).reshape(x.shape)), states)


@pytest.mark.parametrize("name", ["user System, order 4", "heavy top on SO(4), order 1", "quartic kinetic energy"])
def test_node_velocities_equal_the_per_node_inverse_legendre_map(name):
    """``vj.simulate``'s node velocities, solved for all nodes at once on component arrays, equal
    the per-node Newton of ``inverse_legendre`` (to Newton's tolerance), for kinetic energies
    quadratic in the velocities (one Newton step) and not (Newton iterates)."""
    from vi_jax.discrete import inverse_legendre
    from vi_jax.engine._node_velocities import node_velocities

    system, states = _node_problem(name)
    ours = node_velocities(system, states, 64 * EPS, 20)
    theirs = jax.vmap(lambda g, q, M, P, z: inverse_legendre(system, g, q, M, P, z, rtol=64 * EPS, max_iterations=20))(
        states.g, states.q, states.M, states.P, states.z
    )
    for a, b in zip(ours, theirs):
        if b is not None:
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=64 * EPS * float(np.max(np.abs(b))))


@pytest.mark.parametrize("name, loops", [("user System, order 4", 0), ("quartic kinetic energy", 1)])
def test_affine_residuals_are_solved_without_a_loop(name, loops):
    """The member Newton sees from the Jacobian's components that a residual is affine (no entry
    is a member array: the user System's momenta are linear in (ξ, ν)) and solves it with one
    step, compiling no fallback loop; a nonlinear one keeps its loop."""
    from vi_jax.engine._node_velocities import node_velocities

    system, states = _node_problem(name)
    jaxpr = jax.make_jaxpr(lambda s: node_velocities(system, s, 64 * EPS, 20))(states)
    assert str(jaxpr).count("while[") == loops


def test_nothing_behind_ensemble_names_a_model():
    """``vj.ensemble`` and the step it generates hold no model-specific code: no module of the
    engine or of the discrete schemes imports ``vi_jax.models`` or names one of its classes
    (docstrings aside)."""
    import ast
    import pathlib

    models = {name for name in dir(vj.models) if isinstance(getattr(vj.models, name), type)}
    assert {"UnderwaterVehicle", "HeavyTop", "RigidBody"} <= models
    root = pathlib.Path(vj.__file__).parent
    paths = sorted((root / "engine").glob("*.py")) + sorted((root / "discrete").glob("*.py"))
    assert any(p.name == "_ensemble.py" for p in paths) and any(p.name == "_generated_step.py" for p in paths)
    for path in paths:
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                assert "models" not in (node.module or "").split("."), (path.name, node.module)
                assert not models & {a.name for a in node.names}, path.name
            elif isinstance(node, ast.Import):
                assert not any("models" in a.name.split(".") for a in node.names), path.name
            elif isinstance(node, ast.Name):
                assert node.id not in models, (path.name, node.id)
            elif isinstance(node, ast.Attribute):
                assert node.attr not in models, (path.name, node.attr)
