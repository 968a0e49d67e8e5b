"""Saved nodes under transformations: a two-level scan whose blocks, when every step is saved on
XLA:CPU's default loop plan, are as many nodes as keep the step's loop body within the sizes
the thunk executor runs in order (:func:`vi_jax._saved_nodes.step_block`). The blocks change
where the loops split, never the steps: a traced run equals the concrete run at every length
around a block boundary. A concrete run saving every step runs blocks of steps too, in a loop of
traced length whose last block's steps past the run change nothing. Checkpointed reverse mode
on that plan rematerialises step by step in blocks of the same kind."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj
from vi_jax._saved_nodes import (
    SAVE_BLOCK,
    SEQUENTIAL_BYTES,
    one_kernel_plan,
    checkpointed,
    each_step_rematerialised,
    scan_saved_nodes,
    step_block,
)
from vi_jax.discrete import legendre_initial_state
from vi_jax.engine import _advance, _placement
from vi_jax.engine._cpu_tuning import FAST_LOOPS_FLAG

from newton_iterations import assert_rolled_iterations_match

EPS = np.finfo(np.float64).eps
SCENES = (vj.models.UnderwaterVehicle, vj.models.HeavyTop, lambda: vj.models.RigidBody(group=vj.lie.SOn(6)))


def _on_an_accelerator(monkeypatch):
    """Programs traced from now on target a GPU (as far as the loop plans ask)."""
    monkeypatch.setattr(_placement, "target_platform", lambda: "gpu")


def _state(scene, dtype):
    model = scene()
    x0 = jax.tree.map(lambda x: None if x is None else jnp.asarray(x, dtype), model.initial_state())
    return model, legendre_initial_state(model, x0.g, x0.xi, x0.q, x0.qdot)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
@pytest.mark.parametrize("scene", SCENES)
def test_a_block_is_the_most_nodes_whose_largest_leaf_fits(scene, dtype):
    _, state = _state(scene, dtype)
    largest = max(x.size * x.dtype.itemsize for x in jax.tree.leaves(state))
    block = step_block(state)
    assert block & (block - 1) == 0 and 2 <= block <= SAVE_BLOCK
    assert block * largest <= SEQUENTIAL_BYTES or block == 2
    assert 2 * block * largest > SEQUENTIAL_BYTES or block == SAVE_BLOCK


def test_the_block_follows_the_loop_plan(monkeypatch):
    """Blocks of steps only where every step is saved on the CPU with default loops; blocks of
    ``SAVE_BLOCK`` with a node every few steps (their steps run in an inner loop already), with
    the loop option or in a one-kernel region (one kernel per loop: a run saving every step is
    one scan instead) and on an accelerator."""
    _, state = _state(vj.models.UnderwaterVehicle, jnp.float64)
    monkeypatch.setenv("XLA_FLAGS", "")
    assert _advance._node_block(state, 1) == step_block(state) == 4  # 4 rows of a 3×3 float64 g: 288 B
    assert _advance._node_block(state, 2) == SAVE_BLOCK
    _on_an_accelerator(monkeypatch)
    assert _advance._node_block(state, 1) == SAVE_BLOCK
    monkeypatch.undo()
    monkeypatch.setenv("XLA_FLAGS", "")
    assert not _advance._initial_node_in_scan(1)
    with one_kernel_plan():
        assert _advance._node_block(state, 1) == SAVE_BLOCK
        assert _advance._initial_node_in_scan(1) and not _advance._initial_node_in_scan(2)
    monkeypatch.setenv("XLA_FLAGS", FAST_LOOPS_FLAG)
    assert _advance._node_block(state, 1) == SAVE_BLOCK
    assert _advance._initial_node_in_scan(1)  # every node in one scan: no block asked for
    assert not _advance._initial_node_in_scan(2)


def test_a_step_rematerialised_stores_its_input_carry_alone():
    """Each step rematerialised (blocks of 4 steps and a rest): reverse mode stores the steps'
    input carries, nothing of their inside (a plain scan stores six arrays a step here), and
    the gradient is the plain scan's to the bit (the same operations, recomputed)."""
    A = jnp.arange(9.0).reshape(3, 3) / 10

    def step(carry, _):
        x, worst = carry
        y = jnp.tanh(A @ x) * jnp.cos(x) + jnp.exp(-(x**2))
        return (x + 0.1 * y, jnp.maximum(worst, jnp.max(y))), None

    n, x = 10, jnp.array([0.3, -0.2, 0.5])
    each = lambda x: each_step_rematerialised(step, (x, jnp.zeros(())), n, 4)[0]  # noqa: E731
    plain = lambda x: jax.lax.scan(step, (x, jnp.zeros(())), None, length=n)[0][0]  # noqa: E731
    residual_bytes = lambda f: sum(r.nbytes for r in jax.tree.leaves(jax.vjp(f, x)[1]))  # noqa: E731
    assert residual_bytes(each) == A.nbytes + n * x.nbytes
    assert residual_bytes(plain) > A.nbytes + 5 * n * x.nbytes
    gradient = lambda f: jax.grad(lambda x: jnp.sum(f(x) ** 2))(x)  # noqa: E731
    np.testing.assert_array_equal(gradient(each), gradient(plain))


def _scan_lengths(closed):
    """The lengths of every scan in a jaxpr, its sub-jaxprs included."""
    lengths = []
    for eqn in closed.jaxpr.eqns:
        if eqn.primitive.name == "scan":
            lengths.append(eqn.params["length"])
        for value in eqn.params.values():
            for sub in value if isinstance(value, (tuple, list)) else (value,):
                if isinstance(sub, jax.extend.core.ClosedJaxpr):
                    lengths += _scan_lengths(sub)
                elif isinstance(sub, jax.extend.core.Jaxpr):
                    lengths += _scan_lengths(jax.extend.core.ClosedJaxpr(sub, ()))
    return sorted(lengths)


def test_only_differentiation_sees_the_checkpoints():
    """``checkpointed``: without differentiation the steps run in the program without
    checkpoints (one loop of ``n``); a JVP runs the checkpointed one (blocks of 4 and the rest);
    gradients with respect to what the step closes over (hoisted for the custom JVP rule) are
    the plain scan's to the bit, and reverse mode stores the steps' input carries alone."""

    def step_of(a):
        return lambda x, _: (jnp.sin(a * x) + x, None)

    def program(step, x, checkpoint):
        return each_step_rematerialised(step, x, n, 4) if checkpoint else jax.lax.scan(step, x, None, length=n)[0]

    n, a, x = 10, jnp.array(0.7), jnp.array([0.3, -0.2])
    mine = lambda a, x: checkpointed(program, step_of(a), x)  # noqa: E731
    plain = lambda a, x: jax.lax.scan(step_of(a), x, None, length=n)[0]  # noqa: E731
    assert _scan_lengths(jax.make_jaxpr(mine)(a, x)) == [n]
    assert _scan_lengths(jax.make_jaxpr(lambda a, x: jax.jvp(mine, (a, x), (a, x)))(a, x)) == [2, 2, 4]
    residuals = jax.vjp(mine, a, x)[1]
    assert sum(r.size for r in jax.tree.leaves(residuals) if r.size > 1) == n * x.size
    gradient = lambda f: jax.grad(lambda a, x: jnp.sum(f(a, x) ** 2), argnums=(0, 1))(a, x)  # noqa: E731
    for value, reference in zip(gradient(mine), gradient(plain)):
        np.testing.assert_array_equal(value, reference)


@pytest.mark.parametrize("save_every", [1, 3, SAVE_BLOCK + 1])
def test_checkpointed_steps_are_rematerialised_one_by_one_on_the_default_loop_plan(monkeypatch, save_every, fresh_programs):
    """``checkpoint=True`` on XLA:CPU's default loop plan rematerialises every step by itself, in
    blocks whose largest leaf fits ``SEQUENTIAL_BYTES`` (reverse mode through a scan otherwise
    keeps a buffer of the run's length for each of a step's intermediate values, and a loop body
    with such a buffer has its operations handed to the thread pool: ``python
    benchmarks/gradients.py``); not with ``checkpoint=False``, the loop option or on an
    accelerator."""
    model, x0 = vj.models.UnderwaterVehicle(), vj.models.UnderwaterVehicle().initial_state()
    blocks = []

    def recorded(step, carry, n, block):
        largest = max(x.size * x.dtype.itemsize for x in jax.tree.leaves(carry))
        blocks.append((block, largest))
        return each_step_rematerialised(step, carry, n, block)

    def recorded_nodes(*args, nodes=True, blocks=True):
        remat.append((nodes, blocks))
        return scan_saved_nodes(*args, nodes=nodes, blocks=blocks)

    remat = []
    monkeypatch.setattr(_advance, "each_step_rematerialised", recorded)
    monkeypatch.setattr(_advance, "scan_saved_nodes", recorded_nodes)

    def traced(flags, checkpoint=True):
        monkeypatch.setenv("XLA_FLAGS", flags)
        blocks.clear(), remat.clear()
        fresh_programs()  # the plan is chosen at trace time
        loss = lambda m: jnp.sum(vj.simulate(m, x0, 0.01, 2 * save_every, save_every=save_every, checkpoint=checkpoint).q)  # noqa: E731
        jax.make_jaxpr(lambda m: jax.jvp(loss, (m,), (m,)))(model)  # the plan is chosen in the JVP rule
        return list(blocks)

    found = traced("")
    if save_every == 1:  # the node is the step: rematerialised by itself, its blocks not
        assert found == [] and remat[-1] == (True, False)
    else:  # the node's steps are: the node is not, its blocks are
        assert found and all(b * largest <= SEQUENTIAL_BYTES < (b + 1) * largest for b, largest in found)
        assert remat[-1] == (False, True)
    assert traced("", checkpoint=False) == [] and remat
    assert traced(FAST_LOOPS_FLAG) == [] and remat[-1] == (True, True)
    _on_an_accelerator(monkeypatch)
    assert traced("") == [] and remat[-1] == (True, True)


@pytest.mark.parametrize("save_every", [1, 10, SAVE_BLOCK + 1])
def test_checkpoint_leaves_a_program_that_does_not_differentiate_unchanged(monkeypatch, save_every, fresh_programs):
    """``checkpoint=True`` changes what reverse mode stores, never the forward program: under
    ``jit`` without differentiation ``vj.simulate`` lowers to the same program as with
    ``checkpoint=False``, on every loop plan (each step, each node rematerialised)."""
    model, x0 = vj.models.UnderwaterVehicle(), vj.models.UnderwaterVehicle().initial_state()

    def lowered(flags, checkpoint):
        monkeypatch.setenv("XLA_FLAGS", flags)
        fresh_programs()  # the plan is chosen at trace time
        run = lambda m: vj.simulate(m, x0, 0.01, 2 * save_every, save_every=save_every, checkpoint=checkpoint).q  # noqa: E731
        return jax.jit(run).lower(model).as_text(debug_info=False)

    for flags in ("", FAST_LOOPS_FLAG):
        assert lowered(flags, True) == lowered(flags, False)


@pytest.mark.parametrize("n_steps", [1, 3, 4, 5, 11, SAVE_BLOCK + 3])
def test_traced_runs_equal_the_concrete_run_around_block_boundaries(n_steps):
    """Every node, vehicle at order 1 (blocks of 4 nodes): the jitted run (scan in blocks and a
    rest) equals the concrete run (a loop of traced length over blocks) to Newton's tolerance
    (64ε per step, a √n random walk, a factor 4 for its tail), with the same results and the
    iterations of :func:`assert_rolled_iterations_match`, and its times are the nodes'."""
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    concrete = vj.simulate(model, x0, 0.01, n_steps)
    traced = jax.jit(lambda x: vj.simulate(model, x, 0.01, n_steps))(x0)
    assert traced.q.shape == (n_steps + 1, 3)
    np.testing.assert_allclose(np.asarray(traced.t), 0.01 * np.arange(n_steps + 1), rtol=4 * EPS)
    bound = 4 * 64 * EPS * np.sqrt(n_steps)
    for field in ("g", "q", "M", "P", "energy"):
        ours, theirs = np.asarray(getattr(traced, field)), np.asarray(getattr(concrete, field))
        assert np.max(np.abs(ours - theirs)) <= bound * max(np.max(np.abs(theirs)), 1.0), field
    np.testing.assert_array_equal(np.asarray(traced.result), np.asarray(concrete.result))
    assert_rolled_iterations_match(concrete.newton_iterations, traced.newton_iterations)


def test_the_loop_option_plan_puts_the_initial_state_first_without_a_copy(monkeypatch, fresh_programs):
    """With the loop option and every step saved, the traced run scans one more node whose first
    keeps the initial state (:func:`vi_jax.engine._advance._initial_node_first`) instead of
    copying it in front of the nodes: the same Solution as the default plan's (to Newton's
    tolerance per step), the same Newton results (its iterations rolled with the loop option,
    differentiated too: ``_advance._value_step``), and the same gradients, checkpointed or
    not. The plan is read at trace time, so each is traced afresh here."""
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    n_steps = 9

    def run(flags, checkpoint=True):
        monkeypatch.setenv("XLA_FLAGS", flags)
        fresh_programs()

        def loss(xi):
            sol = vj.simulate(model, vj.State(x0.g, xi, x0.q, x0.qdot), 0.01, n_steps, checkpoint=checkpoint)
            return jnp.sum(sol.energy), sol

        return jax.grad(loss, has_aux=True)(x0.xi)[::-1]

    default, grad_default = run("")
    looped, grad_looped = run(FAST_LOOPS_FLAG)
    _, grad_unchecked = run(FAST_LOOPS_FLAG, checkpoint=False)
    bound = 4 * 64 * EPS * np.sqrt(n_steps)
    for field in ("g", "q", "M", "P", "xi", "energy"):
        ours, theirs = np.asarray(getattr(looped, field)), np.asarray(getattr(default, field))
        assert ours.shape == theirs.shape, field
        assert np.max(np.abs(ours - theirs)) <= bound * max(np.max(np.abs(theirs)), 1.0), field
    np.testing.assert_array_equal(np.asarray(looped.g[0]), np.asarray(x0.g))
    np.testing.assert_array_equal(np.asarray(looped.result), np.asarray(default.result))
    assert_rolled_iterations_match(looped.newton_iterations, default.newton_iterations)
    scale = np.max(np.abs(np.asarray(grad_default)))
    for grad in (grad_looped, grad_unchecked):
        assert np.all(np.isfinite(np.asarray(grad)))
        assert np.max(np.abs(np.asarray(grad) - np.asarray(grad_default))) <= bound * scale
