"""``vj.simulate``'s loops as one kernel on XLA:CPU whatever its flags (``in_one_kernel``,
``vi_jax/_saved_nodes.py``): the DEP loops of a scene whose step holds only elementwise
operations reach XLA as one marked call, under a caller's ``jit`` and in the concrete call's
program, planned as with the loop option, Newton's iterations rolled for a single trajectory;
a scene with LAPACK or matrix products in its step, or a loop program too large to compile
quickly as one kernel, keeps the default plan;
differentiation runs the default plan's program (the region's JVP is never taken); the values
are the default plan's to round-off."""

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_generated_step import _user_system
from test_one_kernel import one_kernel_calls

import vi_jax as vj
from vi_jax import _saved_nodes
from vi_jax.engine import _advance, _simulate
from vi_jax.engine._cpu_tuning import FAST_LOOPS_FLAG

EPS = np.finfo(np.float64).eps
SCENES = {
    "vehicle": lambda: (vj.models.UnderwaterVehicle(), vj.models.UnderwaterVehicle().initial_state()),
    "user System": _user_system,
    "heavy top": lambda: (vj.models.HeavyTop(), vj.models.HeavyTop().initial_state()),
}


def _scene(name):
    return SCENES[name]()


def _regions_in_jaxpr(fn, *args):
    return str(jax.make_jaxpr(fn)(*args)).count("vi_jax_one_kernel")


@pytest.mark.parametrize("name", list(SCENES))
def test_the_loops_are_one_kernel_under_jit_and_in_the_concrete_program(name):
    system, x0 = _scene(name)
    run = lambda m, x: vj.simulate(m, x, 0.01, 12, throw=False).g  # noqa: E731
    assert one_kernel_calls(jax.jit(run).lower(system, x0).compile()) == 1
    count = lambda n: jnp.asarray(n, jnp.int32)  # noqa: E731
    options = dict(capacity=16, tau=vj.lie.difference_map("cayley"), rule="left", gammas=(1.0,), rtol=1e-14, max_iter=20)
    for save_every in (1, count(3)):  # every step saved (blocks of steps), a node every few steps
        lowered = _simulate._loop_nodes_jit.lower(system, x0, jnp.asarray(0.01), count(12), save_every, **options)
        assert one_kernel_calls(lowered.compile().compiled) == 1


@pytest.mark.parametrize("order", [1, 2])
def test_lapack_keeps_the_default_plan(order):
    """SO(4): the step's exp map and solves call LAPACK, which XLA:CPU's one kernel cannot. No
    region, the loops planned for the default thunk executor, and the run as before."""
    system = vj.models.RigidBody(group=vj.lie.SOn(4))
    x0 = system.initial_state()
    run = lambda m, x: vj.simulate(m, x, 0.01, 12, order=order, throw=False).g  # noqa: E731
    assert _regions_in_jaxpr(run, system, x0) == 0
    assert one_kernel_calls(jax.jit(run).lower(system, x0).compile()) == 0
    assert np.all(np.isfinite(jax.jit(run)(system, x0)))


def test_a_large_program_keeps_the_default_plan(monkeypatch, fresh_programs):
    """A loop program of more than ``ONE_KERNEL_EQUATIONS`` equations (LLVM compiles a kernel in
    one piece): no region, Newton's iterations not rolled, and the run as before. The shipped
    scenes' programs all fit under ``jit`` now; a bound below the vehicle's makes it too large."""
    system, x0 = _scene("vehicle")
    monkeypatch.setattr(_saved_nodes, "ONE_KERNEL_EQUATIONS", 500)
    monkeypatch.setattr(_advance, "ONE_KERNEL_EQUATIONS", 500)
    rolled = _spy_on_value_steps(monkeypatch)
    run = lambda m, x: vj.simulate(m, x, 0.01, 12, order=2, throw=False).g  # noqa: E731
    assert _regions_in_jaxpr(run, system, x0) == 0
    assert rolled == [False]
    assert one_kernel_calls(jax.jit(run).lower(system, x0).compile()) == 0
    assert np.all(np.isfinite(jax.jit(run)(system, x0)))


def _spy_on_value_steps(monkeypatch):
    """A list receiving, from now on, whether ``_advance._value_step`` gave the value program a
    step of its own (the concrete call's: Newton's iterations rolled, sub-steps of traced count)."""
    answers, decide = [], _advance._value_step

    def spy(make_step, gammas, carry):
        step = decide(make_step, gammas, carry)
        answers.append(step is not None)
        return step

    monkeypatch.setattr(_advance, "_value_step", spy)
    return answers


@pytest.mark.parametrize("name", list(SCENES))
def test_under_jit_one_trajectory_runs_the_concrete_calls_step(name, monkeypatch, fresh_programs):
    """Under ``jit`` a single trajectory's value program runs the concrete call's step (Newton's
    iterations rolled; a composition's sub-steps a loop of traced count) in one kernel: the
    vehicle at order 2 and every scene at order 4 too. A step that a ``jax.vmap`` batches keeps
    the step of static counts."""
    system, x0 = _scene(name)
    own_step = _spy_on_value_steps(monkeypatch)
    for order in (1, 2, 4):
        run = lambda m, x, order=order: vj.simulate(m, x, 0.01, 12, order=order, throw=False).g  # noqa: E731
        assert _regions_in_jaxpr(run, system, x0) == 1
    assert one_kernel_calls(jax.jit(run).lower(system, x0).compile()) == 1  # order 4
    assert own_step and all(own_step)
    own_step.clear()
    xis = jnp.stack([x0.xi, 1.01 * x0.xi])
    for order in (1, 4):
        jax.make_jaxpr(jax.vmap(lambda xi: vj.simulate(system, vj.State(x0.g, xi, x0.q, x0.qdot), 0.01, 12, order=order, throw=False).g))(xis)
    assert own_step == [False, False]


@pytest.mark.parametrize("order", [2, 4])
@pytest.mark.parametrize("name", list(SCENES))
def test_the_concrete_calls_step_equals_the_static_one_to_newtons_tolerance(name, order, monkeypatch, fresh_programs):
    """Rolled, Newton stops at the first iterate within its tolerance; unrolled, it checks once,
    after the chord steps. Each run solves every (sub-)step to that tolerance (64ε relative): over
    a bounded motion the states part by at most about twice that per step of each array's scale."""
    system, x0 = _scene(name)
    n = 100
    run = lambda m, x: vj.simulate(m, x, 0.01, n, order=order, throw=False)  # noqa: E731
    rolled = jax.jit(run)(system, x0)
    monkeypatch.setattr(_advance, "_value_step", lambda make_step, gammas, carry: None)
    fresh_programs()
    unrolled = jax.jit(run)(system, x0)
    for field in ("g", "xi", "q", "M", "P", "energy"):
        a, b = getattr(rolled, field), getattr(unrolled, field)
        if a is None:
            continue
        tol = n * 2 * 64 * EPS * float(jnp.max(jnp.abs(b)))
        np.testing.assert_allclose(a, b, rtol=0, atol=tol, err_msg=field)
    assert np.all(np.asarray(rolled.result) == 0) and np.all(np.asarray(unrolled.result) == 0)


def test_differentiation_runs_the_default_plan():
    """Forward and reverse mode (checkpointed or not) see no region: the custom JVP's rule is the
    JVP of the default plan's program, whose blocks keep reverse mode's buffers small."""
    system, x0 = _scene("vehicle")

    def final_position(scale, checkpoint):
        x = vj.State(x0.g, scale * x0.xi, x0.q, x0.qdot)
        return jnp.sum(vj.simulate(system, x, 0.01, 20, checkpoint=checkpoint).q[-1])

    for checkpoint in (True, False):
        assert _regions_in_jaxpr(lambda s: final_position(s, checkpoint), 1.0) == 1
        assert _regions_in_jaxpr(jax.grad(lambda s: final_position(s, checkpoint)), 1.0) == 0
        assert _regions_in_jaxpr(lambda s: jax.jvp(lambda s: final_position(s, checkpoint), (s,), (1.0,)), 1.0) == 0


@pytest.mark.parametrize("name", list(SCENES))
def test_values_are_the_default_plans_to_round_off(name, monkeypatch, fresh_programs):
    """The same steps in one kernel and thread per fusion: XLA may contract or vectorise their
    arithmetic differently, each step's rounding then differs by a few ulps, and over a bounded
    motion those differences grow at most linearly: 8 ulps per step of each array's scale."""
    system, x0 = _scene(name)
    n = 100
    run = lambda m, x: vj.simulate(m, x, 0.01, n, throw=False)  # noqa: E731
    one = jax.jit(run)(system, x0)
    monkeypatch.setattr(_advance, "in_one_kernel", lambda program: program)
    fresh_programs()  # vj.simulate's traced programs are cached by their arguments
    assert _regions_in_jaxpr(run, system, x0) == 0
    default = jax.jit(run)(system, x0)
    for field in ("g", "xi", "q", "M", "P", "energy"):
        a, b = getattr(one, field), getattr(default, field)
        if a is None:
            continue
        tol = 8 * n * EPS * float(jnp.max(jnp.abs(b)))
        np.testing.assert_allclose(a, b, rtol=0, atol=tol, err_msg=field)
    np.testing.assert_array_equal(one.newton_iterations, default.newton_iterations)
    np.testing.assert_array_equal(one.result, default.result)


# In a fresh process (XLA aborts the process on a program it cannot compile): compositions of
# static length under jit against the concrete call (traced fractions, one kernel), max |Δg|,
# and each scene's gradient at order 4 (the rule's program: static sub-steps, default plan).
_COMPOSITIONS_UNDER_JIT = """
import jax, numpy as np
jax.config.update("jax_enable_x64", True)
import vi_jax as vj
for scene in (vj.models.HeavyTop(), vj.models.RigidBody()):
    x0 = scene.initial_state()
    for order in (4, 6):
        traced = jax.jit(lambda m, x: vj.simulate(m, x, 0.01, N_STEPS, order=order))(scene, x0)
        concrete = vj.simulate(scene, x0, 0.01, N_STEPS, order=order)
        print(float(np.max(np.abs(np.asarray(traced.g) - np.asarray(concrete.g)))))
    energy = lambda s: vj.simulate(scene, vj.State(x0.g, s * x0.xi, None, None), 0.01, N_STEPS, order=4).energy[-1]
    print(float(jax.jit(jax.grad(energy))(1.0)))
"""


@pytest.mark.parametrize("flags", ["", FAST_LOOPS_FLAG])
def test_compositions_under_jit_compile_and_equal_the_concrete_call(flags):
    """The heavy top and the rigid body at orders 4 and 6 under ``jit``, with default XLA and the
    loop option: their value program runs the concrete call's step, its sub-steps a loop of a
    count XLA does not know (with a known count, XLA:CPU aborted compiling it as one kernel:
    ``_advance._default_plan``), and equals the concrete call; their gradients' program (static
    sub-steps) compiles. Each run solves every sub-step to Newton's tolerance (64ε relative):
    their states may part by about that per step."""
    n_steps = 40
    script = _COMPOSITIONS_UNDER_JIT.replace("N_STEPS", str(n_steps))
    env = dict(os.environ, XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} {flags}".strip())
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)
    assert run.returncode == 0, run.stderr[-3000:]
    values = [float(x) for x in run.stdout.split()]
    differences = values[0:2] + values[3:5]
    assert len(values) == 6 and max(differences) <= n_steps * 2 * 64 * EPS, values
    assert np.all(np.isfinite(values[2::3])), values
