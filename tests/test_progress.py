"""``vj.simulate(progress=True)`` (DEP) runs the same steps as the plain run, in ≤ 100 pieces
of one compiled loop with a progress bar between them. (The splitting's progress path:
tests/test_splitting.py.)"""

import numpy as np
import pytest

import vi_jax as vj

N_STEPS, SAVE_EVERY = 250, 2  # 125 saved nodes: 100 pieces of one or two nodes


@pytest.mark.parametrize("order", [1, 4])  # the left rule; a trapezoid composition (traced fractions)
def test_progress_run_equals_the_plain_run(order, capsys):
    model = vj.models.RigidBody()
    x0 = model.initial_state()
    plain = vj.simulate(model, x0, 0.01, N_STEPS, save_every=SAVE_EVERY, order=order)
    shown = vj.simulate(model, x0, 0.01, N_STEPS, save_every=SAVE_EVERY, order=order, progress=True)
    assert f"{N_STEPS}/{N_STEPS}" in capsys.readouterr().err  # the bar reached the end
    np.testing.assert_array_equal(shown.t, plain.t)
    np.testing.assert_array_equal(shown.newton_iterations, plain.newton_iterations)
    # The same operations in two compiled programs: XLA may contract or order a few of them
    # differently (≲ a few ulps per step), and a difference grows at most linearly over a run
    # this short; 8 ulps per step bounds it.
    bound = 8 * N_STEPS * np.finfo(np.float64).eps
    for name in ("g", "xi", "M", "energy", "kelvin_noether"):
        a, b = np.asarray(getattr(shown, name)), np.asarray(getattr(plain, name))
        assert a.shape == b.shape, name
        assert np.max(np.abs(a - b)) <= bound * np.max(np.abs(b)), name


@pytest.mark.parametrize("method", ["batched", "vmap"])
def test_ensemble_progress_run_equals_the_plain_run(method, monkeypatch, capsys):
    """Five members in groups of three (the last one padded with a copy of its last member),
    against plain runs of members 0–2 and 2–4 (the same program: three members)."""
    from vi_jax.engine import _ensemble

    monkeypatch.setattr(_ensemble, "MIN_GROUP", 2)
    rng = np.random.default_rng(0)
    if method == "batched":  # the generated step, the vehicle
        model, field = vj.models.UnderwaterVehicle(), "mass"
        values = 123.8 + rng.uniform(-5, 5, size=5)
    else:
        model, field = vj.models.RigidBody(), "inertia"
        values = np.diag([0.5, 0.6, 1.0]) * rng.uniform(0.9, 1.1, size=(5, 1, 1))
    n_steps = 60
    run = lambda members, **kw: vj.ensemble(  # noqa: E731
        vj.vary(model, **{field: members}), model.initial_state(), 0.02, n_steps,
        system_axes=0, x0_axes=None, method=method, save_every=5, **kw
    )
    shown = run(values, progress=True)
    assert f"{5 * n_steps}/{5 * n_steps}" in capsys.readouterr().err
    first, last = run(values[:3]), run(values[2:])
    # The generated step is elementwise over members, and jax.vmap of vj.simulate updates only
    # the members whose Newton solve has not converged: a member's place in its group changes
    # nothing; allow XLA a few ulps per step in the vmap path all the same (8, added over the run).
    bound = 0.0 if method == "batched" else 8 * n_steps * np.finfo(np.float64).eps
    for name in ("g", "xi", "M", "energy", "kelvin_noether", "newton_iterations"):
        a = np.asarray(getattr(shown, name))
        b = np.concatenate([np.asarray(getattr(first, name)), np.asarray(getattr(last, name))[1:]])
        assert a.shape == b.shape, name
        assert np.max(np.abs(a - b)) <= bound * np.max(np.abs(b)), name
