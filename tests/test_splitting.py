"""Explicit splitting of separable scenes through ``vj.simulate``/``vj.ensemble(scheme="splitting")``
(issue 12; the compositions' orders are in tests/test_splitting_orders.py): the driver equals the
plain step loop; Kelvin–Noether, the vehicle's horizontal linear momentum and R ∈ SO(3) hold to
round-off over 10⁶ steps with the energy bounded and trend-free; one step equals an independent
hand-written Strang step for the heavy top; non-separable scenes are rejected; ensembles, vmap,
reverse-mode gradients and float32 work.
"""

import functools
import json
import math
import os
import subprocess
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_splitting_orders import hand_reference, run_steps

import vi_jax as vj
from vi_jax._diagnostics import kelvin_noether
from vi_jax.discrete import _splitting as S
from vi_jax.discrete import _splitting_pieces as splitting_pieces
from vi_jax.discrete._splitting_pieces import principal_axes, separable_parts
from vi_jax.lie import SE3, SO3, LinearAction, SOn

EPS = float(np.finfo(np.float64).eps)
VEHICLE = vj.models.UnderwaterVehicle()
TOP = vj.models.HeavyTop()
FULL_INERTIA = np.array([[2.0, 0.3, -0.1], [0.3, 1.5, 0.2], [-0.1, 0.2, 1.0]])


# --- the driver -----------------------------------------------------------------------------------
def assert_same_arithmetic(got, want, *, n_steps, flows_per_step, label=None):
    """Two runs of the same steps, compiled differently (batched, merged across steps, in
    pieces): the same operations up to association (a lowering may reorder sums, depending on the
    compiler and CPU), so ≲ 1 ulp of difference per sub-flow, adding up over the steps (the
    motion is bounded)."""
    bound = flows_per_step * n_steps * EPS * (1 + float(jnp.max(jnp.abs(want))))
    assert float(jnp.max(jnp.abs(got - want))) <= bound, label


def _vehicle_run(x0, model=VEHICLE):
    return S.splitting_run(model, x0, 0.05, 200, order=4, save_every=50)


def test_run_equals_the_steps_at_every_node():
    """splitting_run (first/last flows merged across the steps of a node) = the plain step loop."""
    x0 = VEHICLE.initial_state()
    out = _vehicle_run(x0)
    assert out.g.shape == (5, 3, 3) and out.xi.shape == (5, 3)
    np.testing.assert_array_equal(out.g[0], x0.g)
    for k, n in enumerate((50, 100, 150, 200), start=1):
        g, q, M, P = run_steps(VEHICLE, x0, 0.05, n, 4)
        for got, want in ((out.g[k], g), (out.q[k], q), (out.M[k], M), (out.P[k], P)):
            assert_same_arithmetic(got, want, n_steps=n, flows_per_step=3 * 6)  # order 4: 6 stages
    # Node velocities are J⁻¹Π and M⁻¹P (hand: the models' matrices).
    np.testing.assert_allclose(out.xi, np.linalg.solve(VEHICLE.inertia, np.asarray(out.M).T).T, rtol=1e-13)
    mass = VEHICLE.mass * np.eye(3) + VEHICLE.added_mass
    np.testing.assert_allclose(out.nu, np.linalg.solve(mass, np.asarray(out.P).T).T, rtol=1e-13)


def test_simulate_returns_the_run_as_a_solution():
    """``vj.simulate(scheme="splitting")`` (with and without the progress bar, which runs the same
    steps in pieces) holds the driver's nodes, the scene's energy and Kelvin–Noether at them,
    and no Newton statistics (an explicit scheme)."""
    x0 = VEHICLE.initial_state()
    out = _vehicle_run(x0)
    for progress in (False, True):
        sol = vj.simulate(VEHICLE, x0, 0.05, 200, scheme="splitting", order=4, save_every=50, progress=progress)
        for name in ("g", "q", "M", "P", "xi", "nu"):
            assert_same_arithmetic(getattr(sol, name), getattr(out, name), n_steps=200, flows_per_step=3 * 6, label=name)
        np.testing.assert_allclose(sol.t, 2.5 * np.arange(5), rtol=1e-15)
        n_body, a = jax.vmap(VEHICLE.body_configuration)(sol.g, sol.q), jax.vmap(VEHICLE.body_advected)(sol.g)
        np.testing.assert_allclose(sol.energy, jax.vmap(VEHICLE.energy)(sol.xi, n_body, sol.nu, a), rtol=1e-14)
        kn = jax.vmap(lambda *s: kelvin_noether(VEHICLE, *s))(sol.g, sol.q, sol.M, sol.P)[:, 0]
        np.testing.assert_allclose(sol.kelvin_noether, kn, rtol=1e-14)
        assert not np.any(sol.newton_iterations) and not np.any(sol.result) and bool(sol.succeeded)


def test_simulate_rejects_what_does_not_apply():
    x0 = VEHICLE.initial_state()
    with pytest.raises(ValueError, match="tau: applies to scheme='dep' only"):
        vj.simulate(VEHICLE, x0, 0.05, 10, scheme="splitting", tau="exp")
    with pytest.raises(ValueError, match=r"order: expected one of \(2, 4, 6, 8\), got 1"):
        vj.simulate(VEHICLE, x0, 0.05, 10, scheme="splitting", order=1)
    with pytest.raises(ValueError, match="scheme: expected one of"):
        vj.simulate(VEHICLE, x0, 0.05, 10, scheme="rk4")


LONG_RUNS = {
    # scene, initial state, h, what the test adds: the neutrally buoyant vehicle in motion
    # (bounded energy surface), and the symmetric heavy top, whose Π₃ and |Π| stay constant, so
    # that its rotations turn by the same angles step after step (a rounding repeated every
    # step would drift, 4e-10 after 10⁶ steps before the rotations were applied as increments)
    "vehicle": lambda: (
        (m := vj.models.UnderwaterVehicle(buoyancy=123.8 * 9.81)),
        m.initial_state(omega0=jnp.array([0.6, -0.4, 0.8]), v0=jnp.array([0.3, -0.2, 0.1])), 0.05,
    ),
    "symmetric heavy top": lambda: ((m := vj.models.HeavyTop()), m.initial_state(), 0.005),
}


@pytest.mark.parametrize("scene", list(LONG_RUNS))
@pytest.mark.parametrize("polynomial_plan", [False, True], ids=["jnp trig", "small-angle polynomials"])
def test_long_run_invariants(polynomial_plan, scene, monkeypatch, fresh_programs):
    """10⁶ steps through ``vj.simulate``: every piece commutes with the symmetry, so
    Kelvin–Noether (vertical angular momentum) and the vehicle's horizontal linear momentum RP
    hold to round-off, R stays on SO(3) (products of rotations); the energy error of a symplectic
    composition oscillates without a trend. Both rotation plans: half-angle ``jnp.sin``/``jnp.cos``
    (XLA's default flags) and the small-angle polynomials (the loop option), whose rounding must
    not make the rotations drift off SO(3) either."""
    # fresh_programs: the plan is chosen at trace time, no program is traced under the other one
    monkeypatch.setattr(splitting_pieces, "loop_option_requested", lambda: polynomial_plan)
    model, x0, h = LONG_RUNS[scene]()
    n, every = 1_000_000, 1000
    sol = vj.simulate(model, x0, h, n, scheme="splitting", order=2, save_every=every)
    # Each of the ≤ 8 flows of a step rounds to ~ε; independent roundings add up like a random
    # walk, √(8n) ε; 10√(8n) ε leaves room while a drift (~8n ε = 2e-9) would fail.
    bound = 10 * math.sqrt(8 * n) * EPS
    kn, scale = sol.kelvin_noether, sol.kelvin_noether_scale
    assert float(jnp.max(jnp.abs(kn - kn[0]))) <= bound * float(jnp.max(scale))
    if model.has_additional:
        p_space = jnp.einsum("tij,tj->ti", sol.g, sol.P)[:, :2]
        assert float(jnp.max(jnp.abs(p_space - p_space[0]))) <= bound * float(jnp.max(jnp.abs(sol.P)))
    assert float(jnp.max(vj.group_constraint_residual(model, sol.g))) <= bound
    error = np.asarray(sol.energy) / float(sol.energy[0]) - 1
    t = np.asarray(sol.t)
    trend = np.polyfit(t, error, 1)[0] * t[-1]
    amplitude = np.max(np.abs(error))
    assert amplitude <= 1e-3, amplitude  # an O(h²) oscillation (measured 2.1e-4 vehicle, 1.1e-5 top)
    # Over thousands of periods a bounded oscillation fits a line of slope ~amplitude/T; a
    # drift (non-symplectic RK) makes the fitted change comparable to the amplitude itself.
    assert abs(trend) <= 0.05 * amplitude, (trend, amplitude)


@pytest.mark.parametrize("sphere", [True, False], ids=["sphere piece", "planar rotations"])
def test_heavy_top_equals_a_hand_written_strang_step(sphere):
    """Strang's splitting of the heavy top written from the physics: half kick of the gravity
    torque mg Γ×χ (Γ = Rᵀe_z), and rotations about the body axes, ω_k = Π_k/I_k,
    R ← R·rot_k(tω_k), Π ← rot_kᵀΠ, composed symmetrically in the module's documented order of
    the pieces for order 2. With the sphere piece (I₁ = 0.8, the middle moment):
    R ← R·expm(tΠ̂/I₁), Π unchanged, and the rotations about axes 0 and 2 with 1/I_k − 1/I₁."""
    moments, chi = np.array([1.0, 0.8, 0.4]), np.array([0.05, -0.1, 0.5])
    top = vj.models.HeavyTop(inertia=moments, center_of_mass=chi)
    mgchi = float(top.mass * top.gravity) * jnp.asarray(chi)
    rates = 1 / moments - (1 / moments[1] if sphere else 0.0)

    def rot(k, th):
        c, s = jnp.cos(th), jnp.sin(th)
        i, j = (k + 1) % 3, (k + 2) % 3
        return jnp.eye(3).at[i, i].set(c).at[j, j].set(c).at[j, i].set(s).at[i, j].set(-s)

    def kick(R, Pi, t):
        return R, Pi + t * jnp.cross(R[2], mgchi)

    def axis(R, Pi, k, t):
        Q = rot(k, t * Pi[k] * rates[k])
        return R @ Q, Q.T @ Pi

    def sphere_piece(R, Pi, t):
        w = t * Pi / moments[1]
        hat = jnp.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
        return R @ jax.scipy.linalg.expm(hat), Pi

    # Strang over the pieces in the module's documented order, outermost first (the potential
    # kick "V", the sphere piece "S", the body axes; the top has no translation): X₁(h/2)…X_m(h)…X₁(h/2).
    axes = (0, 2) if sphere else (0, 1, 2)
    hand = {"V": kick, **({"S": sphere_piece} if sphere else {})}
    hand.update({k: functools.partial(lambda R, Pi, t, k: axis(R, Pi, k, t), k=k) for k in axes})
    pieces = [hand[p] for p in S.arrange(tuple(hand), S.resolve(2, sphere=sphere)[1])]

    def hand_step(carry, _):
        R, Pi = carry
        for piece in pieces[:-1]:
            R, Pi = piece(R, Pi, h / 2)
        R, Pi = pieces[-1](R, Pi, h)
        for piece in reversed(pieces[:-1]):
            R, Pi = piece(R, Pi, h / 2)
        return (R, Pi), None

    h, n = 0.01, 100
    x0 = top.initial_state()
    (R, Pi), _ = jax.lax.scan(hand_step, (x0.g, jnp.asarray(moments) * x0.xi), None, length=n)
    out = S.splitting_run(top, x0, h, n, order=2, save_every=n, arrangement=S.resolve(2, sphere=sphere)[1])
    # Same operations up to association (expm and Rodrigues: both rounded to ~1 ulp): X₁…X₄…X₁
    # is 7 flows per step.
    assert_same_arithmetic(out.g[-1], R, n_steps=n, flows_per_step=7)
    assert_same_arithmetic(out.M[-1], Pi, n_steps=n, flows_per_step=7)


def test_free_symmetric_top_is_exact_with_the_sphere_piece():
    """Without gravity (χ = 0) and with I₁ = I₂, the rotational energy is ½|Π|²/I₁ plus
    ½Π₃²(1/I₃ − 1/I₁), two commuting pieces: the sphere arrangement is the exact flow for any
    step (one step of 5 s turns the body by 30 rad about e₃), the planar one is not. Reference:
    scipy's DOP853 at rtol = atol = 1e-13 on the hand-written field (accurate to ~1e-12)."""
    top = vj.models.HeavyTop(center_of_mass=(0.0, 0.0, 0.0))
    T = 5.0
    R_ref, _ = hand_reference(top, T)
    for order in (2, 6):
        for n in (1, 5):
            out = S.splitting_run(top, top.initial_state(), T / n, n, order=order, save_every=n)
            assert float(jnp.max(jnp.abs(out.g[-1] - R_ref))) <= 1e-11, (order, n)
    planar = S.splitting_run(top, top.initial_state(), T / 5, 5, order=2, save_every=5, arrangement=S.resolve(2, sphere=False)[1])
    assert float(jnp.max(jnp.abs(planar.g[-1] - R_ref))) > 1e-3


# --- scenes the splitting cannot take -------------------------------------------------------------
def _scene(lagrangian, group=SO3(), advected=True, rho=None):
    return vj.System(
        group, lagrangian, advected=(LinearAction(group, rho), np.eye(group.matrix_size)[-1]) if advected else None,
    )


NOT_SEPARABLE = {
    # term named in the error: its coefficient in the scene below
    "cross term ξ–ν": "cross",
    "rotational kinetic energy depends on the configuration": "inertia_n",
    "not quadratic in ξ": "quartic",
    "translational kinetic energy depends on the configuration": "mass_a",
    "linear in the velocities": "linear",
    "not positive definite": "negative",
}


_A0 = np.eye(3)[2]  # one object: System keeps a₀ in a static field, compared by identity


def _coupled(xi, n, nu, a, c):
    """A separable ℓ when every coefficient is 0; one scene function, so that all cases share one
    compilation of the checks."""
    kinetic = 0.5 * (1 - 2 * c["negative"] + c["inertia_n"] * n @ n) * xi @ xi + 0.5 * (1 + c["mass_a"] * a[0] ** 2) * nu @ nu
    return kinetic + c["cross"] * xi @ nu + c["quartic"] * (xi @ xi) ** 2 + c["linear"] * xi @ a - n @ a


@pytest.mark.parametrize("term", list(NOT_SEPARABLE))
def test_non_separable_scene_is_rejected(term):
    coefficients = {k: jnp.asarray(1.0 if k == NOT_SEPARABLE[term] else 0.0) for k in NOT_SEPARABLE.values()}
    scene = vj.System(SO3(), _coupled, coefficients, advected=(LinearAction(SO3()), _A0), additional=LinearAction(SO3()))
    x0 = vj.State(jnp.eye(3), jnp.ones(3), jnp.zeros(3), jnp.ones(3))
    with pytest.raises(ValueError, match=term):
        S.splitting_run(scene, x0, 0.1, 10)
    separable_parts(eqx.tree_at(lambda s: s.params, scene, {k: jnp.asarray(0.0) for k in coefficients}))  # passes


def test_non_separable_traced_scene_raises_at_run_time():
    """With the scene's parameters traced (jit, grad, vmap over scenes) the same check runs as an
    eqx.error_if: an error at run time, never silently wrong numbers."""
    coefficients = {k: jnp.asarray(1.0 if k == "linear" else 0.0) for k in NOT_SEPARABLE.values()}
    scene = vj.System(SO3(), _coupled, coefficients, advected=(LinearAction(SO3()), _A0), additional=LinearAction(SO3()))
    x0 = vj.State(jnp.eye(3), jnp.ones(3), jnp.zeros(3), jnp.ones(3))
    run = jax.jit(lambda c: S.splitting_run(eqx.tree_at(lambda s: s.params, scene, c), x0, 0.1, 10).g)
    with pytest.raises(RuntimeError, match="linear in the velocities"):
        jax.block_until_ready(run(coefficients))


def test_non_separable_traced_scene_without_throw_is_flagged():
    """``throw=False`` (as for the DEP scheme): no run-time error, the result code
    ``NOT_SEPARABLE`` after the initial node and NaN nodes; a separable scene runs as usual."""
    scene = vj.System(SO3(), _coupled, {k: jnp.asarray(0.0) for k in NOT_SEPARABLE.values()},
                      advected=(LinearAction(SO3()), _A0), additional=LinearAction(SO3()))
    x0 = vj.State(jnp.eye(3), jnp.ones(3), jnp.zeros(3), jnp.ones(3))
    run = jax.jit(lambda c: vj.simulate(eqx.tree_at(lambda s: s.params, scene, c), x0, 0.1, 10, scheme="splitting", throw=False))
    bad = run({k: jnp.asarray(1.0 if k == "linear" else 0.0) for k in NOT_SEPARABLE.values()})
    assert int(bad.result[0]) == vj.solvers.SUCCESS and np.all(np.asarray(bad.result[1:]) == vj.solvers.NOT_SEPARABLE)
    assert np.all(np.isnan(np.asarray(bad.g[1:]))) and not bool(bad.succeeded)
    good = run({k: jnp.asarray(0.0) for k in NOT_SEPARABLE.values()})
    assert bool(good.succeeded) and np.all(np.isfinite(np.asarray(good.g)))


def test_unsupported_groups_and_actions_are_rejected():
    ell = lambda xi, n, nu, a, p: 0.5 * xi @ xi  # noqa: E731
    with pytest.raises(ValueError, match="supports SO3"):
        separable_parts(_scene(ell, group=SE3(), advected=False))
    with pytest.raises(ValueError, match="defining representation"):
        separable_parts(_scene(lambda xi, n, nu, a, p: 0.5 * xi @ xi - a[0], rho=lambda g: g @ g))
    full = np.eye(6) + 0.1 * (np.ones((6, 6)) - np.eye(6))  # SPD, not diagonal
    with pytest.raises(ValueError, match="not diagonal in the standard basis"):
        separable_parts(vj.models.RigidBody(group=SOn(4), inertia=full))
    # The sphere piece is SO(3)'s: asked for on SO(n) it is an error, by default it is left out.
    top4 = vj.models.HeavyTop(group=SOn(4))
    with pytest.raises(ValueError, match="sphere piece"):
        S.splitting_run(top4, top4.initial_state(), 0.01, 2, order=2, arrangement=("V", "S", "R"))
    assert "S" not in S.resolve(2, sphere=False)[1]
    assert np.all(np.isfinite(S.splitting_run(top4, top4.initial_state(), 0.01, 2, order=2).g))


# --- vmap, gradients --------------------------------------------------------------------------------
def test_vmap_equals_member_by_member():
    """Members differ in initial state and in parameters (traced: the checks run as error_if,
    each member has its own principal frame, one with a non-diagonal inertia)."""
    omegas = jnp.array([[0.1, 0.2, 0.3], [0.0, 0.0, 0.0], [-0.5, 0.4, 0.2]])
    x0s = [VEHICLE.initial_state(omega0=w) for w in omegas]
    full = vj.models.UnderwaterVehicle(inertia=FULL_INERTIA + 4 * np.eye(3))
    models = [VEHICLE, full, vj.models.UnderwaterVehicle(buoyancy=1210.0)]
    stack = lambda trees: jax.tree.map(lambda *xs: jnp.stack(xs), *trees)  # noqa: E731
    batched = jax.vmap(_vehicle_run)(stack(x0s), stack(models))
    for k in range(3):
        single = _vehicle_run(x0s[k], models[k])
        for got, want in zip(jax.tree.leaves(batched), jax.tree.leaves(single)):
            assert_same_arithmetic(got[k], want, n_steps=200, flows_per_step=3 * 6)  # order 4: 6 stages


def test_ensemble_equals_simulate_member_by_member():
    """``vj.ensemble(scheme="splitting")``: members in initial state and parameters."""
    omegas = jnp.array([[0.1, 0.2, 0.3], [0.0, 0.0, 0.0], [-0.5, 0.4, 0.2]])
    models = vj.vary(VEHICLE, buoyancy=jnp.array([1200.0, 1210.0, 1190.0]))
    sol = vj.ensemble(models, vj.vary(VEHICLE.initial_state(), xi=omegas), 0.05, 200, system_axes=0,
                      scheme="splitting", order=6, save_every=50)
    for k in range(3):
        model = vj.models.UnderwaterVehicle(buoyancy=[1200.0, 1210.0, 1190.0][k])
        x0 = model.initial_state(omega0=omegas[k])
        single = vj.simulate(model, x0, 0.05, 200, scheme="splitting", order=6, save_every=50)
        for name in ("g", "q", "xi", "nu", "M", "P", "energy", "kelvin_noether"):
            want = getattr(single, name)
            got = getattr(sol, name)[k]
            assert_same_arithmetic(got, want, n_steps=200, flows_per_step=3 * 10, label=(k, name))  # order 6: 10 stages


def _loss(out):
    weights = jnp.arange(9.0).reshape(3, 3)
    loss = jnp.sum(out.g[-1] * weights) + jnp.sum(out.xi[-1])
    return loss if out.q is None else loss + jnp.sum(out.q[-1] ** 2) + jnp.sum(out.P[-1])


def _check_directional(f, x, grad, direction, eps):
    exact = float(jnp.vdot(grad, direction))
    approx = float((f(x + eps * direction) - f(x - eps * direction)) / (2 * eps))
    # Central differences: O(eps²) truncation and O(ε/eps) round-off, both ≲ 1e-9 relative here.
    assert abs(exact - approx) <= 1e-6 * max(abs(exact), 1e-8), (exact, approx)


def test_gradients_match_central_differences():
    """Plain reverse mode through ``vj.simulate``'s checkpointed scan, one gradient for every
    vehicle parameter (a full
    symmetric direction of the inertia moves the principal frame), the initial velocity and h."""
    x0 = VEHICLE.initial_state()

    def loss(args):
        model, xi, h = args
        x = vj.State(x0.g, xi, x0.q, x0.qdot)
        return _loss(vj.simulate(model, x, h, 200, scheme="splitting", order=4, save_every=50))

    args = (VEHICLE, x0.xi, jnp.asarray(0.05))
    grads = eqx.filter_grad(loss)(args)
    rng = np.random.default_rng(0)
    for name in ("mass", "added_mass", "inertia", "buoyancy", "buoyancy_offset"):
        value = getattr(VEHICLE, name)
        direction = jnp.asarray(rng.normal(size=value.shape))
        direction = direction + direction.T if value.ndim == 2 else direction
        grad = getattr(grads[0], name)
        assert np.all(np.isfinite(grad)), name
        along = lambda v, name=name: loss((eqx.tree_at(lambda m: getattr(m, name), VEHICLE, v), *args[1:]))  # noqa: E731
        _check_directional(along, value, grad, direction, 1e-6 * float(jnp.max(jnp.abs(value))))
    _check_directional(lambda w: loss((VEHICLE, w, args[2])), x0.xi, grads[1], jnp.array([0.3, -0.2, 0.5]), 1e-6)
    _check_directional(lambda h: loss((VEHICLE, x0.xi, h)), args[2], grads[2], jnp.asarray(1.0), 1e-7)


@pytest.mark.parametrize("save_every", [1, 3])
def test_checkpointed_gradient_equals_plain_gradient(save_every):
    """``checkpoint=True`` (the default) only rematerialises — on XLA:CPU's default loop plan
    every node saved runs in blocks of nodes each rematerialised, a node every few steps has each
    stage rematerialised: the gradient equals the stored one to round-off (1e-12 relative; a
    recomputed stage is the same arithmetic)."""
    x0 = VEHICLE.initial_state()

    def loss(model, checkpoint):
        return _loss(vj.simulate(model, x0, 0.05, 24, scheme="splitting", order=4, save_every=save_every, checkpoint=checkpoint))

    plain, checkpointed = (eqx.filter_grad(loss)(VEHICLE, c) for c in (False, True))
    for a, b in zip(jax.tree.leaves(plain), jax.tree.leaves(checkpointed), strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * float(np.max(np.abs(a))))


@pytest.mark.parametrize("save_every", [1, 3])
def test_the_rematerialisation_follows_the_loop_plan(monkeypatch, save_every, fresh_programs):
    """On XLA:CPU's default loop plan: every node saved in blocks of ``step_block`` nodes, the
    nodes rematerialised and not their blocks; a node every few steps with each stage
    rematerialised (in blocks of stages) and not the node. With the loop option: blocks of
    ``SAVE_BLOCK`` nodes, nodes and blocks rematerialised, as before."""
    from vi_jax import _saved_nodes
    from vi_jax.engine._cpu_tuning import FAST_LOOPS_FLAG

    stages, scans = [], []

    def each_stage(*args):
        stages.append(args[-1])
        return _saved_nodes.each_step_rematerialised(*args)

    def scan(node, phase, n, checkpoint, block=_saved_nodes.SAVE_BLOCK, **remat):
        scans.append((block, remat))
        return _saved_nodes.scan_saved_nodes(node, phase, n, checkpoint, block, **remat)

    monkeypatch.setattr(S, "each_step_rematerialised", each_stage)
    monkeypatch.setattr(S, "scan_saved_nodes", scan)
    x0 = VEHICLE.initial_state()

    def traced(flags):
        monkeypatch.setenv("XLA_FLAGS", flags)
        stages.clear(), scans.clear()
        fresh_programs()  # the plan is chosen at trace time
        loss = lambda m: _loss(vj.simulate(m, x0, 0.05, 2 * save_every, scheme="splitting", save_every=save_every))  # noqa: E731
        jax.make_jaxpr(eqx.filter_grad(loss))(VEHICLE)
        return list(stages), list(scans)

    found_stages, found_scans = traced("")
    if save_every == 1:
        ((block, remat),) = found_scans
        assert found_stages == [] and 2 <= block < _saved_nodes.SAVE_BLOCK and remat == {"blocks": False}
    else:
        assert found_stages and found_scans == [(_saved_nodes.SAVE_BLOCK, {"nodes": False})]
    assert traced(FAST_LOOPS_FLAG) == ([], [(_saved_nodes.SAVE_BLOCK, {"nodes": True})])


def test_principal_axes_derivative():
    """The JVP of J ↦ (U, I) against central differences for a full J (eigenvectors turn), and
    finite at equal moments (the heavy top's (1, 1, 0.4)), where along a diagonal direction the
    frame stays and dI is the direction's diagonal."""
    J = jnp.asarray(FULL_INERTIA)
    dJ = jnp.asarray([[0.3, -0.2, 0.1], [-0.2, 0.5, 0.4], [0.1, 0.4, -0.6]])
    (U, I), (dU, dI) = jax.jvp(principal_axes, (J,), (dJ,))
    eps = 1e-6
    (Up, Ip), (Um, Im) = principal_axes(J + eps * dJ), principal_axes(J - eps * dJ)
    np.testing.assert_allclose(dU, (Up - Um) / (2 * eps), atol=1e-8)
    np.testing.assert_allclose(dI, (Ip - Im) / (2 * eps), atol=1e-8)
    direction = jnp.diag(jnp.array([1.0, -0.5, 0.3]))
    (U, I), (dU, dI) = jax.jvp(principal_axes, (TOP.inertia,), (direction,))
    np.testing.assert_array_equal(U, np.eye(3))
    np.testing.assert_array_equal(dU, np.zeros((3, 3)))
    np.testing.assert_allclose(dI, [1.0, -0.5, 0.3], rtol=1e-15)


# --- float32 ------------------------------------------------------------------------------------
FLOAT32_SCRIPT = r"""
import json
import jax
import jax.numpy as jnp
import numpy as np
import vi_jax as vj
m = vj.models.UnderwaterVehicle()
model = vj.models.UnderwaterVehicle(buoyancy=m.mass * m.gravity)  # W − B = 0 exactly in float32 too
x0 = model.initial_state(omega0=jnp.array([0.6, -0.4, 0.8]), v0=jnp.array([0.3, -0.2, 0.1]))
out = vj.simulate(model, x0, 0.05, 200, scheme="splitting", order=4, save_every=50)
result = {k: np.asarray(getattr(out, k)[-1], np.float64).tolist() for k in ("g", "q", "M", "P")}
result.update(dtype=str(out.g.dtype), kn=np.asarray(out.kelvin_noether, np.float64).ravel().tolist(),
              kn_scale=float(out.kelvin_noether_scale.max()),
              orthogonality=float(vj.group_constraint_residual(model, out.g).max()))
print(json.dumps(result))
"""


def test_float32_runs_at_float32_accuracy():
    """200 steps in a float32 process (x64 off) against float64 from the same float32-rounded
    parameters, initial data and h, so that the runs differ by arithmetic round-off only. Each of
    the ~48 flows of an order-4 step rounds to ~ε₃₂, and these add up like √(48n)·ε₃₂ (the
    motion over 10 s amplifies them little: measured 2–4 √n·ε₃₂); a lost digit or a float64
    leak would show. Kelvin–Noether and RᵀR = I hold to the same float32 round-off."""
    env = {**os.environ, "JAX_ENABLE_X64": "0"}
    proc = subprocess.run([sys.executable, "-c", FLOAT32_SCRIPT], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr
    single = json.loads(proc.stdout.strip().splitlines()[-1])
    assert single["dtype"] == "float32"
    as32 = lambda tree: jax.tree.map(lambda x: jnp.asarray(np.asarray(x, np.float32), np.float64), tree)  # noqa: E731
    m = as32(VEHICLE)
    model = eqx.tree_at(lambda v: v.buoyancy, m, m.mass * m.gravity)
    x0 = as32(model.initial_state(omega0=jnp.array([0.6, -0.4, 0.8]), v0=jnp.array([0.3, -0.2, 0.1])))
    double = S.splitting_run(model, x0, float(np.float32(0.05)), 200, order=4, save_every=50)
    bound = 10 * math.sqrt(48 * 200) * float(np.finfo(np.float32).eps)
    for k in ("g", "q", "M", "P"):
        want = np.asarray(getattr(double, k)[-1])
        assert np.max(np.abs(np.asarray(single[k]) - want)) <= bound * np.max(np.abs(want)), k
    kn = np.asarray(single["kn"])
    assert np.max(np.abs(kn - kn[0])) <= bound * single["kn_scale"]
    assert single["orthogonality"] <= bound
