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
