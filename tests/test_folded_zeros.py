"""A concrete ensemble's generated step folds the scene's entries that are exactly zero for
every member (a diagonal inertia's off-diagonal entries, an offset's zero components): the
products with them vanish at trace time, each pattern of zeros gets its own program, and the
members keep ``vj.simulate``'s values."""

import jax
import numpy as np

import vi_jax as vj
from vi_jax.engine import _ensemble, _generated_step
from vi_jax.engine._member_split import leaf_axes

EPS = np.finfo(np.float64).eps
N_MEMBERS = 5
OFF_DIAGONAL = (1, 2, 3, 5, 6, 7)  # flat indices of a 3×3 matrix's off-diagonal entries
DIAGONAL = np.diag([0.5, 0.6, 1.0])
COUPLED = DIAGONAL + 0.1 * (np.eye(3)[[1, 0, 2]] - np.diag([0.0, 0.0, 1.0]))  # the (0, 1) pair 0.1


def _states(x0, seed=0):
    rng = np.random.default_rng(seed)
    return vj.vary(x0, xi=np.asarray(x0.xi) + 0.1 * rng.normal(size=(N_MEMBERS, 3)))


def _inertias(coupled_member=None):
    """Per member the diagonal inertia, but ``coupled_member``'s, which couples axes 0 and 1."""
    inertia = np.repeat(DIAGONAL[None], N_MEMBERS, axis=0)
    if coupled_member is not None:
        inertia[coupled_member] = COUPLED
    return inertia


def _zeros(system, system_axes):
    return _generated_step.zero_entries(system, leaf_axes("system_axes", system, system_axes))


def test_zero_entries_are_those_zero_for_every_member(monkeypatch):
    """Shared leaves: their zero entries; leaves with a member axis: the entries zero for every
    member (one member's off-diagonal pair keeps the pair), found on the host or, for a large
    leaf, where it lives; traced leaves: none."""
    top = vj.models.HeavyTop(inertia=[0.5, 0.6, 1.0], center_of_mass=[0.0, 0.0, 0.3])
    leaves = [np.asarray(x) for x in jax.tree.leaves(top)]
    zeros = dict(zip([x.shape for x in leaves], _zeros(top, None)))
    assert zeros == {(3, 3): OFF_DIAGONAL, (3,): (0, 1), (): ()}  # inertia, centre of mass; mass and gravity

    for large in (1 << 20, 1):  # reduced on the host; where the leaf lives (a large leaf)
        monkeypatch.setattr(_generated_step, "LARGE_LEAF", large)
        assert _zeros(vj.vary(vj.models.RigidBody(), inertia=_inertias()), 0) == (OFF_DIAGONAL,)
        assert _zeros(vj.vary(vj.models.RigidBody(), inertia=_inertias(coupled_member=3)), 0) == ((2, 5, 6, 7),)

    seen = []

    @jax.jit
    def traced(body):
        seen.append(_zeros(body, None))
        return body.inertia

    traced(vj.models.RigidBody(inertia=DIAGONAL))
    assert seen == [((),)]


def test_folded_zeros_take_work_out_of_the_step():
    """The heavy top's residual, and its residual with the Jacobian: the products with its
    inertia's six zero entries and its centre of mass's two vanish."""
    top = vj.models.HeavyTop()
    states = _states(top.initial_state())
    counts = {folded: _generated_step.scene_operations(top, states, 0.01, order=1, folded=folded) for folded in (False, True)}
    assert counts[True][0] < counts[False][0] and counts[True][1] < counts[False][1], counts


def test_known_scenes_fold_their_zeros(monkeypatch, fresh_programs):
    """The step is traced with the scene's zeros where its values are known (``FOLD_ZEROS``): in
    a concrete call and under a ``jit`` that closes over the scene; not where the scene is
    traced (a ``jit`` argument: differentiable), nor with the switch off."""
    folded = []
    with_zeros = _generated_step._with_zeros

    def spy(params, zeros):
        folded.append(zeros)
        return with_zeros(params, zeros)

    monkeypatch.setattr(_generated_step, "_with_zeros", spy)
    body = vj.models.RigidBody(inertia=DIAGONAL)
    states = _states(body.initial_state())
    run = lambda body, states: vj.ensemble(body, states, 0.01, 8, save_every=8, method="batched").g  # noqa: E731
    calls = {"concrete": lambda: run(body, states), "closed over": lambda: jax.jit(lambda s: run(body, s))(states),
             "traced": lambda: jax.jit(run)(body, states)}
    for switch in (True, False):
        monkeypatch.setattr(_ensemble, "FOLD_ZEROS", switch)
        finals = {}
        for name, call in calls.items():
            fresh_programs()  # traced afresh
            folded.clear()
            finals[name] = np.asarray(call())[:, -1]
            assert folded == ([(OFF_DIAGONAL,)] if switch and name != "traced" else []), (switch, name)
        for name in ("concrete", "closed over"):  # Newton's tolerance 64ε a step, 8 steps
            np.testing.assert_allclose(finals[name], finals["traced"], rtol=0, atol=4 * 64 * EPS * np.sqrt(8))


def test_each_pattern_of_zeros_gets_its_program_and_simulate_values():
    """Scenes of one shape and dtype, diagonal then not, one call after the other (the programs
    kept between concrete calls must not mix them up: the coupled inertia's off-diagonal pair
    changes the motion by far more than the tolerance), and a member whose pair is not zero
    among members whose are: every member equals its own ``vj.simulate`` run (each step stops
    within Newton's tolerance 64ε: a random walk of √n such steps, with a factor 4 for its tail)."""
    states = _states(vj.models.RigidBody().initial_state())
    n_steps = 60
    rtol = 4 * 64 * EPS * np.sqrt(n_steps)
    cases = [(vj.models.RigidBody(inertia=DIAGONAL), None), (vj.models.RigidBody(inertia=COUPLED), None),
             (vj.vary(vj.models.RigidBody(), inertia=_inertias(coupled_member=3)), 0)]
    for system, axes in cases:
        sol = vj.ensemble(system, states, 0.01, n_steps, save_every=6, system_axes=axes, method="batched")
        for k in (0, 3):
            member = system if axes is None else jax.tree.map(lambda x: x[k], system)
            ref = vj.simulate(member, jax.tree.map(lambda x: x[k], states), 0.01, n_steps, save_every=6)
            for field in ("g", "xi"):
                ours, theirs = np.asarray(getattr(sol, field)[k]), np.asarray(getattr(ref, field))
                assert np.max(np.abs(ours - theirs)) <= rtol * max(np.max(np.abs(theirs)), 1.0), (k, field, np.max(np.abs(ours - theirs)))
            coupled = bool(np.asarray(member.inertia)[0, 1])
            other = vj.simulate(vj.models.RigidBody(inertia=DIAGONAL if coupled else COUPLED), jax.tree.map(lambda x: x[k], states), 0.01,
                                n_steps, save_every=6)
            assert np.max(np.abs(np.asarray(other.xi) - np.asarray(ref.xi))) > 1e3 * rtol  # the patterns' motions differ
