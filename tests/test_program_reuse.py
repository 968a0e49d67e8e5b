"""``vj.simulate`` on concrete inputs compiles one program per scene and scheme for every run of
up to 1024 saved nodes: the step counts are traced integers, the saved-node buffer has a
minimum capacity (a new program costs seconds of compilation, ``python benchmarks/capacity.py``);
orders 2, 4 and 6 share one program (their sub-step fractions are traced). The beam's time
march likewise. Building a scene compiles almost nothing, and Newton traces a step's residual once."""

import logging
import subprocess
import sys

import equinox as eqx
import jax
import numpy as np

import vi_jax as vj
from vi_jax.solvers import newton_root

# The programs of a concrete DEP vj.simulate: the loop, then the node diagnostics.
CONCRETE_DEP_PROGRAMS = ("jit(_loop_nodes)", "jit(_node_rows)")

# In a fresh process: the programs that building each scene and its initial state asks for (each
# eager operation on concrete values is one, 20–50 ms to compile on a 2-core machine).
_SETUP_PROGRAMS = """
import logging, jax
jax.config.update("jax_enable_x64", True)
import vi_jax as vj
compiled = []
handler = logging.Handler()
handler.emit = lambda record: compiled.append(record.getMessage()) if record.getMessage().startswith("Compiling ") else None
logging.getLogger("jax").addHandler(handler)
logging.getLogger("jax").setLevel(logging.DEBUG)
with jax.log_compiles():
    for scene in (vj.models.UnderwaterVehicle, vj.models.HeavyTop, vj.models.RigidBody):
        jax.block_until_ready(scene().initial_state())
        print(scene.__name__, len(compiled))
        compiled.clear()
"""


def test_runs_of_different_lengths_share_one_program(caplog):
    model = vj.models.RigidBody()
    x0 = model.initial_state()
    vj.simulate(model, x0, 0.01, 10)  # compiles (or finds) the program saving every step
    vj.simulate(model, x0, 0.01, 20, save_every=2)  # and the one saving every k-th step
    with jax.log_compiles(), caplog.at_level(logging.DEBUG, logger="jax"):
        long = vj.simulate(model, x0, 0.01, 1024)
        sparse = vj.simulate(model, x0, 0.01, 3072, save_every=3)
    assert long.g.shape[0] == sparse.g.shape[0] == 1025
    compiled = [r.getMessage() for r in caplog.records if r.getMessage().startswith(tuple(f"Compiling {p}" for p in CONCRETE_DEP_PROGRAMS))]
    assert compiled == []


def test_orders_2_4_and_6_share_one_program(caplog):
    """The trapezoid compositions' sub-step fractions are traced data: one program for the three."""
    model = vj.models.HeavyTop()  # as in tests/test_orders.py, whose runs this one shares
    x0 = model.initial_state()
    runs = {2: vj.simulate(model, x0, 0.05, 20, order=2)}
    with jax.log_compiles(), caplog.at_level(logging.DEBUG, logger="jax"):
        runs.update({order: vj.simulate(model, x0, 0.05, 20, order=order) for order in (4, 6)})
    finals = [np.asarray(sol.g[-1]) for sol in runs.values()]
    assert not any(np.array_equal(a, b) for a, b in zip(finals, finals[1:]))  # different schemes ran
    compiled = [r.getMessage() for r in caplog.records if r.getMessage().startswith(tuple(f"Compiling {p}" for p in CONCRETE_DEP_PROGRAMS))]
    assert compiled == []


def test_beam_time_marches_of_every_length_share_one_program(caplog):
    """The time march on concrete inputs (traced step counts, ``while`` loops) equals the
    traced march (static counts, ``lax.scan``: what ``jit``, ``vmap`` and ``grad`` run), and
    another length or saving interval compiles nothing."""
    model = vj.models.GeometricallyExactBeam()
    ds = float(model.length) / 4
    dt = 0.5 * float(model.stable_time_step(ds))
    g0, xi0 = model.initial_state(4)

    def march(g0, n_steps, save_every):
        return vj.multisymplectic.time_march(model, g0, xi0=xi0, dt=dt, ds=ds, n_steps=n_steps, save_every=save_every)

    loop = march(g0, 12, 3)
    scan = eqx.filter_jit(march)(g0, 12, 3)
    with jax.log_compiles(), caplog.at_level(logging.DEBUG, logger="jax"):
        every_row = march(g0, 40, 1)
    compiled = [r.getMessage() for r in caplog.records if r.getMessage().startswith("Compiling jit(_time_march_loop)")]
    assert compiled == []
    assert every_row.g.shape[0] == 41 and loop.g.shape[0] == 5
    # The same operations in different programs (or two copies of a row in one): XLA may contract
    # or order a few of them differently, ≲ a few ulps per step, growing at most linearly here.
    bound = 8 * 40 * np.finfo(np.float64).eps
    for other, rows in ((scan, slice(None)), (every_row, slice(0, 13, 3))):
        np.testing.assert_array_equal(np.asarray(other.t)[rows], loop.t)
        np.testing.assert_array_equal(other.s, loop.s)
        for name in ("g", "xi", "eta", "mu", "p", "momentum", "energy"):
            a, b = np.asarray(getattr(other, name))[rows], np.asarray(getattr(loop, name))
            assert np.max(np.abs(a - b)) <= bound * np.max(np.abs(b)), name
    # Newton statistics of a saved row: its own solve's and the worst of the unsaved steps after it
    np.testing.assert_array_equal(scan.newton_iterations, loop.newton_iterations)
    each = np.asarray(every_row.newton_iterations)
    expected = [np.maximum(each[3 * i], each[3 * i + 1 : 3 * i + 3].max()) for i in range(4)] + [each[12]]
    np.testing.assert_array_equal(loop.newton_iterations, np.stack(expected))


def test_ensemble_runs_of_different_lengths_share_one_program(caplog):
    """``vj.ensemble`` on concrete inputs (both paths) takes traced step counts: another
    ``n_steps`` or ``save_every`` with the same saved-node capacity compiles nothing, and the
    run equals the traced one (static lengths: what ``jit`` runs) to round-off."""
    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    states = vj.vary(x0, xi=np.asarray(x0.xi) + 0.3 * np.random.default_rng(1).normal(size=(3, 3)))
    for method in ("batched", "vmap"):
        first = vj.ensemble(model, states, 0.02, 60, save_every=4, method=method)  # 15 nodes: capacity 16
        traced = eqx.filter_jit(lambda s, method=method: vj.ensemble(model, s, 0.02, 60, save_every=4, method=method))(states)
        for name in ("g", "q", "M", "P", "energy", "t", "newton_iterations"):
            ours, theirs = np.asarray(getattr(first, name)), np.asarray(getattr(traced, name))
            assert ours.shape == theirs.shape == (3, 16) + ours.shape[2:], name
            assert np.max(np.abs(ours - theirs)) <= 1e-12 * max(np.max(np.abs(theirs)), 1.0), name
        with jax.log_compiles(), caplog.at_level(logging.DEBUG, logger="jax"):
            other = vj.ensemble(model, states, 0.02, 36, save_every=3, method=method)  # 12 nodes
            full = vj.ensemble(model, states, 0.02, 64, save_every=4, method=method)  # 16: the whole buffer
        assert full.q.shape == (3, 17, 3)
        np.testing.assert_array_equal(np.asarray(full.q[:, :16]), np.asarray(first.q))
        compiled = [r.getMessage() for r in caplog.records if r.getMessage().startswith("Compiling jit(_run_loop)")]
        assert compiled == [], method
        assert other.q.shape == (3, 13, 3)
        np.testing.assert_array_equal(np.asarray(other.t[0]), 0.06 * np.arange(13))


def test_splitting_runs_of_different_lengths_share_one_program(caplog):
    """The splitting on concrete inputs takes traced step counts as the DEP scheme does: equal to
    the traced run (static lengths, what ``jit`` runs) to round-off, and another length or saving
    interval with the same capacity compiles nothing."""
    model = vj.models.HeavyTop()
    x0 = model.initial_state()
    looped = vj.simulate(model, x0, 0.05, 200, scheme="splitting", order=4, save_every=4)
    traced = eqx.filter_jit(lambda m, x: vj.simulate(m, x, 0.05, 200, scheme="splitting", order=4, save_every=4))(model, x0)
    for name in ("g", "M", "xi", "energy", "kelvin_noether", "t"):
        ours, theirs = np.asarray(getattr(looped, name)), np.asarray(getattr(traced, name))
        assert ours.shape == theirs.shape == (51,) + ours.shape[1:], name
        assert np.max(np.abs(ours - theirs)) <= 1e-12 * max(np.max(np.abs(theirs)), 1.0), name
    with jax.log_compiles(), caplog.at_level(logging.DEBUG, logger="jax"):
        other = vj.simulate(model, x0, 0.05, 300, scheme="splitting", order=4, save_every=3)
    compiled = [r.getMessage() for r in caplog.records if r.getMessage().startswith("Compiling jit(_run_loop)")]
    assert compiled == []
    assert other.g.shape[0] == 101


def test_building_a_scene_compiles_few_programs():
    """Validation and default initial states run in NumPy or in one jitted function, not op by op
    (43 programs, 0.8–1.2 s, for the vehicle before; 8 now, most of them device transfers): at
    most 16 programs per scene, room for another JAX version's transfers, none for op by op."""
    out = subprocess.run([sys.executable, "-c", _SETUP_PROGRAMS], capture_output=True, text=True, check=True).stdout
    counts = {name: int(n) for name, n in (line.split() for line in out.splitlines())}
    assert set(counts) == {"UnderwaterVehicle", "HeavyTop", "RigidBody"}
    assert all(n <= 16 for n in counts.values()), counts


def _first_call_programs(scene, *calls):
    """In a fresh process: the names of the programs that ``calls`` (``vj.simulate`` argument
    strings after the scene and its initial state) compile, one after the other; "next" between
    the calls."""
    runs = "\n    print('next')\n".join(f"    vj.simulate(model, x0, {call})" for call in calls)
    script = f"""
import logging, jax
jax.config.update("jax_enable_x64", True)
import vi_jax as vj
model = vj.models.{scene}()
x0 = jax.block_until_ready(model.initial_state())
handler = logging.Handler()
handler.emit = lambda record: print(record.getMessage().split()[1]) if record.getMessage().startswith("Compiling ") else None
logging.getLogger("jax").addHandler(handler)
logging.getLogger("jax").setLevel(logging.DEBUG)
with jax.log_compiles():
{runs}
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout.split()
    per_call = [[]]
    for name in out:
        if name == "next":
            per_call.append([])
        else:
            per_call[-1].append(name)
    return per_call


def test_a_first_call_compiles_no_conversion():
    """The step size and the step counts reach the run's program without an eager conversion
    (each a program to compile, 15–20 ms: ``jnp.asarray`` of a number compiles one)."""
    (programs,) = _first_call_programs("UnderwaterVehicle", "0.01, 100")
    assert not [p for p in programs if "convert_element_type" in p or "stage" in p], programs


def test_a_first_call_compiles_its_two_programs_once():
    """The loop's program, compiled on a thread while the node diagnostics' program is traced
    for the avals of its outputs, is the one the call runs, and so is that one (placeholders of
    other avals would compile both again); a second call compiles nothing."""
    first, second = _first_call_programs("UnderwaterVehicle", "0.01, 100", "0.01, 200")
    assert sorted(p for p in first if p in CONCRETE_DEP_PROGRAMS) == sorted(CONCRETE_DEP_PROGRAMS), first
    assert second == [], second


def test_a_first_splitting_call_compiles_no_eager_operation():
    """The splitting's set-up (J, M and the frame: ``_derive``; the algebra axes: one program of
    hat and ad; the separability verdict, read on the host) and its loop: no program for a single
    operation (each 15–100 ms to compile; ~25 of them before)."""
    (programs,) = _first_call_programs("HeavyTop", "0.01, 100, scheme='splitting'")
    assert "jit(_run_loop)" in programs, programs
    assert [p for p in programs if p not in ("jit(_derive)", "jit(_run_loop)", "jit(<lambda>)")] == [], programs


def test_newton_traces_the_residual_once():
    """The Jacobian, the chord steps, the full iterations and the implicit-function gradient
    replay the residual's jaxpr (Python model code runs once per step traced)."""
    calls = []

    def root(z0):
        def fn(z):  # a new closure per step, as the engine's
            calls.append(1)
            return z**3 - 8.0, 8.0

        return newton_root(fn, z0, rtol=1e-13, max_iterations=20)[0]

    z = jax.jit(root)(np.array([1.8, 2.5]))  # far enough from 2 for the full iterations
    np.testing.assert_allclose(z, [2.0, 2.0], rtol=1e-14)
    assert len(calls) == 1
    calls.clear()
    np.testing.assert_allclose(jax.jacfwd(lambda a: root(a * np.array([1.8, 2.5])).sum())(1.0), 0.0, atol=1e-12)
    assert len(calls) == 1
