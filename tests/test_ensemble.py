"""Ensembles: both code paths equal ``vj.simulate`` member by member, per-member Newton
convergence, conservation per member, chunking/padding, float32, gradients, bad input."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj
from vi_jax.engine._ensemble import CHUNK, ensemble, member_converged, vary
from vi_jax.engine._simulate import NewtonFailure
from vi_jax.solvers import SINGULAR_DIFFERENCE_MAP, SUCCESS

MODEL = vj.models.UnderwaterVehicle()
X0 = MODEL.initial_state()
H, N_STEPS, SAVE_EVERY = 0.02, 240, 8
FIELDS = ["t", "g", "xi", "q", "nu", "M", "P", "energy", "kelvin_noether", "kelvin_noether_scale"]
B = 5

rng = np.random.default_rng(4)
OMEGAS = np.asarray(X0.xi) + 0.4 * rng.normal(size=(B, 3))
VELOCITIES = np.asarray(X0.qdot) + 0.2 * rng.normal(size=(B, 3))
MASSES = 123.8 + rng.uniform(-10, 10, size=B)
OFFSETS = np.array([0.0, 0.0, -0.007]) + 0.01 * rng.normal(size=(B, 3))
MODELS = vary(MODEL, mass=MASSES, buoyancy_offset=OFFSETS)
STATES = vary(X0, xi=OMEGAS, qdot=VELOCITIES)


def member(k):
    model = vj.models.UnderwaterVehicle(mass=MASSES[k], buoyancy_offset=OFFSETS[k])
    return model, vj.State(g=X0.g, xi=jnp.asarray(OMEGAS[k]), q=X0.q, qdot=jnp.asarray(VELOCITIES[k]))


@functools.lru_cache
def references(tau):
    return [vj.simulate(*member(k), H, N_STEPS, tau=tau, save_every=SAVE_EVERY) for k in range(B)]


def assert_members_equal(sol, refs, rtol):
    for k, ref in enumerate(refs):
        for name in FIELDS:
            ours, theirs = np.asarray(getattr(sol, name)[k]), np.asarray(getattr(ref, name))
            assert ours.shape == theirs.shape, name
            scale = max(np.max(np.abs(theirs)), 1e-300)
            assert np.max(np.abs(ours - theirs)) <= rtol * scale, (k, name, np.max(np.abs(ours - theirs)) / scale)


@pytest.mark.parametrize("method", ["batched", "vmap"])
def test_ensemble_equals_simulate_member_by_member(method):
    """Initial states and parameters batched together; every member's trajectory and
    diagnostics equal its own unbatched run (vmap: the same equations, compiled batched and
    unbatched, so each step may stop at a different iterate within Newton's tolerance 64ε: a
    random walk of √n such steps, with a factor 4 for its tail; batched: the step generated from
    the same Lagrangian, ν solved first as in eq. 74, equal to round-off; τ = exp: next test)."""
    refs = references("cayley")
    sol = ensemble(MODELS, STATES, H, N_STEPS, system_axes=0, save_every=SAVE_EVERY, method=method)
    assert sol.q.shape == (B, N_STEPS // SAVE_EVERY + 1, 3)
    vmap_rtol = 4 * 64 * np.finfo(np.float64).eps * np.sqrt(N_STEPS)
    assert_members_equal(sol, refs, vmap_rtol if method == "vmap" else 1e-10)
    assert np.all(np.asarray(member_converged(sol)))
    assert np.max(np.asarray(sol.newton_residual)) <= 64 * np.finfo(float).eps
    # Smooth members converge on the common path (Newton + 2 chord steps) at every step; the
    # generated step (its chord steps checked on the vehicle) stops at the first converged
    # iterate, as the concrete vj.simulate's rolled loop does, here after one chord step.
    iterations = np.asarray(sol.newton_iterations)[:, 1:]
    if method == "vmap":
        assert np.all(iterations == 3)
    else:
        np.testing.assert_array_equal(iterations, np.stack([np.asarray(r.newton_iterations)[1:] for r in refs]))
        assert np.all(iterations[:, 1:] < 3)


def test_chunks_padding_and_conservation_per_member():
    """More members than one chunk (and not a multiple of it): every member equals its own
    run, and each conserves its Kelvin–Noether quantity to round-off."""
    n = CHUNK + 6
    omegas = np.asarray(X0.xi) + 0.4 * np.random.default_rng(5).normal(size=(n, 3))
    omegas[:B] = OMEGAS
    states = vary(X0, xi=omegas)
    sol = ensemble(MODEL, states, H, N_STEPS, save_every=SAVE_EVERY)
    for k in (0, CHUNK - 1, CHUNK, n - 1):
        ref = vj.simulate(MODEL, vj.State(X0.g, jnp.asarray(omegas[k]), X0.q, X0.qdot), H, N_STEPS, save_every=SAVE_EVERY)
        for name in FIELDS:
            ours, theirs = np.asarray(getattr(sol, name)[k]), np.asarray(getattr(ref, name))
            assert np.max(np.abs(ours - theirs)) <= 1e-10 * np.max(np.abs(theirs)), (k, name)
    kn = np.asarray(sol.kelvin_noether)
    scale = np.max(np.asarray(sol.kelvin_noether_scale), axis=1)
    assert np.all(np.max(np.abs(kn - kn[:, :1]), axis=1) <= 1e-13 * scale)
    assert len(set(np.round(kn[:, 0], 12))) == n  # the members really differ


def test_whole_batch_plan_equals_the_chunked_plan(monkeypatch):
    """The accelerator plan (every member in every kernel) against the CPU plan (chunks of
    ``CHUNK`` members one after another), both run here: the same scheme on the same members,
    equal to round-off (XLA may contract or vectorise the two programs differently: a few ε per
    step over 240 steps, far below the bound 1e-12); the plan follows the platform the run is
    placed on."""
    from vi_jax.engine import _ensemble

    assert _ensemble.target_platform() == jax.default_backend()
    assert _ensemble.target_platform(jax.make_mesh((1,), ("members",), devices=jax.devices("cpu")[:1])) == "cpu"
    n = CHUNK + 6
    states = vary(X0, xi=np.asarray(X0.xi) + 0.4 * np.random.default_rng(6).normal(size=(n, 3)))
    plans = {}
    for platform in ("cpu", "gpu"):
        monkeypatch.setattr(_ensemble, "target_platform", lambda mesh=None, p=platform: p)
        plans[platform] = ensemble(MODEL, states, H, N_STEPS, save_every=SAVE_EVERY, method="batched")
    for name in FIELDS:
        ours, theirs = np.asarray(getattr(plans["gpu"], name)), np.asarray(getattr(plans["cpu"], name))
        assert ours.shape == theirs.shape == (n,) + ours.shape[1:], name
        assert np.max(np.abs(ours - theirs)) <= 1e-12 * np.max(np.abs(theirs)), name


def test_batched_products_switch_the_small_products_to_dots_at_trace_time():
    """``batched_products`` (the ensemble's CPU plan for its ``vmap`` path) lowers the small
    products to dots while active, to the same values; outside it they stay elementwise."""
    from vi_jax.lie._small import batched_products, dot, matmul, matvec

    a, b = jnp.asarray(np.random.default_rng(7).normal(size=(2, 5, 3, 3)))
    x = b[..., 0]

    def products(a, b, x):
        return matmul(a, b), matvec(a, x), dot(x, x)

    def has_dot():  # a new function each time: make_jaxpr caches traces by function
        return "dot_general" in str(jax.make_jaxpr(lambda *args: products(*args))(a, b, x))

    fused = products(a, b, x)
    assert not has_dot()
    with batched_products():
        assert has_dot()
        dots = products(a, b, x)
    assert not has_dot()
    for u, v in zip(fused, dots):
        np.testing.assert_allclose(u, v, rtol=8 * np.finfo(np.float64).eps, atol=8 * np.finfo(np.float64).eps)


def test_per_member_convergence_is_reported():
    """τ = exp with one member rotating by more than π per step: that member is flagged
    (singular τ), the others are unaffected and equal their own runs (trajectories and
    diagnostics); throw=True names it."""
    omegas = OMEGAS.copy()
    omegas[1] = [0.0, 0.0, 1.2 * np.pi / H]
    states = vary(X0, xi=omegas)
    sol = ensemble(MODEL, states, H, N_STEPS, tau="exp", save_every=SAVE_EVERY, throw=False)
    assert np.asarray(member_converged(sol)).tolist() == [True, False, True, True, True]
    assert np.asarray(sol.result)[1, 1] == SINGULAR_DIFFERENCE_MAP
    assert np.all(np.asarray(sol.result)[[0, 2, 3, 4]] == SUCCESS)
    for k in (0, 2):
        ref = vj.simulate(MODEL, vj.State(X0.g, jnp.asarray(omegas[k]), X0.q, X0.qdot), H, N_STEPS, tau="exp", save_every=SAVE_EVERY)
        for name in FIELDS:
            ours, theirs = np.asarray(getattr(sol, name)[k]), np.asarray(getattr(ref, name))
            assert np.max(np.abs(ours - theirs)) <= 1e-10 * np.max(np.abs(theirs)), (k, name)
    with pytest.raises(NewtonFailure, match=r"1 of 5 members failed \(members \[1\]\)"):
        ensemble(MODEL, states, H, N_STEPS, tau="exp", save_every=SAVE_EVERY)


def test_float32_runs_and_agrees_with_float64():
    states32 = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), STATES)
    sol32 = ensemble(MODEL, states32, H, N_STEPS, save_every=SAVE_EVERY, rtol=1e-5)
    sol64 = ensemble(MODEL, STATES, H, N_STEPS, save_every=SAVE_EVERY)
    assert sol32.q.dtype == jnp.float32
    assert np.all(np.asarray(member_converged(sol32)))
    np.testing.assert_allclose(sol32.q, sol64.q, rtol=0, atol=1e-4)


def test_batched_step_gradients_match_finite_differences():
    """Reverse mode through the batched step's implicit steps, per-member parameters, against
    central differences of the same step."""

    def loss(models):
        sol = ensemble(models, STATES, H, N_STEPS, system_axes=0, save_every=SAVE_EVERY, method="batched")
        return jnp.sum(sol.q[:, -1] ** 2) + jnp.sum(sol.R[:, -1, 2])

    grads = eqx.filter_jit(eqx.filter_grad(loss))(MODELS)
    rng = np.random.default_rng(6)
    for name in ["mass", "added_mass", "inertia", "buoyancy", "buoyancy_offset"]:
        value = getattr(MODELS, name)
        direction = rng.normal(size=value.shape)
        if value.ndim == 3:
            direction = direction + np.swapaxes(direction, 1, 2)
        eps = 1e-6 * float(jnp.max(jnp.abs(value)))
        along = lambda x, name=name: float(loss(eqx.tree_at(lambda m: getattr(m, name), MODELS, x)))  # noqa: E731
        fd = (along(value + eps * direction) - along(value - eps * direction)) / (2 * eps)
        exact = float(jnp.vdot(getattr(grads, name), direction))
        assert abs(exact - fd) <= 1e-6 * abs(exact), (name, exact, fd)


@pytest.mark.parametrize("save_every", [SAVE_EVERY, N_STEPS])
def test_batched_step_checkpointed_gradient_equals_plain_gradient(save_every):
    """``checkpoint=True`` (the default) only rematerialises: the gradient equals the stored
    one to 1e-12 relative (the same operations, recomputed; ``N_STEPS`` > the 128-node block
    exercises the √save_every blocks between two saved nodes)."""

    def loss(models, checkpoint):
        sol = ensemble(models, STATES, H, N_STEPS, system_axes=0, save_every=save_every, method="batched", checkpoint=checkpoint)
        return jnp.sum(sol.q ** 2) + jnp.sum(sol.M[:, -1])

    grads = [eqx.filter_jit(eqx.filter_grad(loss))(MODELS, c) for c in (True, False)]
    for a, b in zip(jax.tree.leaves(grads[0]), jax.tree.leaves(grads[1])):
        assert np.max(np.abs(np.asarray(a) - np.asarray(b))) <= 1e-12 * np.max(np.abs(np.asarray(b)))


BAD = [
    (dict(method="fast"), r"method: expected one of \('auto', 'batched', 'vmap'\), got 'fast'"),
    (dict(x0_axes=1), r"x0_axes: expected 0 \(batched\), None \(shared\)"),
    (dict(x0_axes=None), r"system_axes, x0_axes: expected at least one batched argument"),
    (dict(system=vary(MODEL, mass=np.full(4, 120.0)), system_axes=0), r"batched leaves must share one member count"),
    (dict(mesh="cpu"), r"mesh: expected a jax.sharding.Mesh, got str"),
    (dict(h=-1.0), r"h: expected a finite number > 0"),
    (dict(x0=vary(X0, g=np.stack([np.eye(3), 2 * np.eye(3), np.eye(3), np.eye(3), np.eye(3)]))),
     r"x0.g: expected elements of SO3 for every member, got membership error 12.2 in members \[1\]$"),
    (dict(x0=vary(X0, xi=np.where(np.arange(B)[:, None] == 3, np.nan, OMEGAS))),
     r"x0.xi: expected finite values for every member, got non-finite values in members \[3\]$"),
    (dict(system=vary(MODEL, mass=np.where(np.arange(B) % 2, np.inf, MASSES)), system_axes=0),
     r"system parameters: expected finite values for every member, got non-finite values in members \[1, 3\]$"),
    (dict(system=eqx.tree_at(lambda m: m.inertia, MODEL, jnp.full((3, 3), jnp.nan))), r"system parameters: expected finite values, got \[\[nan"),
]


@pytest.mark.parametrize("overrides, message", BAD, ids=[m[:30] for _, m in BAD])
def test_ensemble_rejects_bad_input(overrides, message):
    kwargs = dict(system=MODEL, x0=STATES, h=H, n_steps=10)
    kwargs.update(overrides)
    with pytest.raises(ValueError, match=message):
        ensemble(kwargs.pop("system"), kwargs.pop("x0"), kwargs.pop("h"), kwargs.pop("n_steps"), **kwargs)


@pytest.mark.parametrize(
    "fields, message",
    [
        (dict(speed=np.ones(3)), r"speed: not a field of UnderwaterVehicle"),
        (dict(mass=np.ones((3, 2))), r"mass: expected shape \(members,\) \+ \(\), got shape \(3, 2\)"),
        (dict(mass=np.ones(3), buoyancy=np.ones(4)), r"fields: expected one member count for all fields"),
        ({}, r"fields: expected at least one field=values pair"),
    ],
)
def test_vary_rejects_bad_input(fields, message):
    with pytest.raises(ValueError, match=message):
        vary(MODEL, **fields)
