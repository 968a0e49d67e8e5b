"""Forward mode through the implicit steps (jacfwd, for least squares) against central
differences, for the physical parameters, the initial state and the step size; checkpointed
reverse mode (``simulate(checkpoint=True)``) equal to the plain one. (Reverse mode against
finite differences: tests/test_gradients.py.)"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import vi_jax as vj
from vi_jax.fitting import Parametrisation

MODEL = vj.models.UnderwaterVehicle()
X0 = MODEL.initial_state()
PARAM = Parametrisation(MODEL)


def observables(z, n_steps=300, save_every=100):
    """Positions and attitudes at t = 1, 2, 3 s (h = 0.01) as a function of
    z = (θ of the 11 physical parameters, v₀, ω₀, log h)."""
    model = PARAM.decode(z[:11])
    x0 = vj.State(g=X0.g, xi=z[14:17], q=X0.q, qdot=z[11:14])
    sol = vj.simulate(model, x0, jnp.exp(z[17]), n_steps, save_every=save_every)
    return jnp.concatenate([sol.q[1:].ravel(), sol.R[1:].ravel()])


Z = jnp.concatenate([PARAM.encode(MODEL), X0.qdot, X0.xi, jnp.log(jnp.array([0.01]))])


def test_forward_mode_matches_central_differences():
    """jacfwd through the implicit steps, column by column: every parameter, v₀, ω₀ and h."""
    value_and_jacobian = jax.jit(lambda z: (observables(z), jax.jacfwd(observables)(z)))
    _, J = value_and_jacobian(Z)
    assert J.shape == (36, 18)
    eps = 1e-6
    for col in range(Z.size):
        e = jnp.zeros(Z.size).at[col].set(eps)
        fd = (value_and_jacobian(Z + e)[0] - value_and_jacobian(Z - e)[0]) / (2 * eps)
        scale = float(jnp.max(jnp.abs(J[:, col])))
        assert scale > 0, col
        assert float(jnp.max(jnp.abs(J[:, col] - fd))) <= 1e-6 * scale, (col, float(jnp.max(jnp.abs(J[:, col] - fd))) / scale)


TOP = vj.models.HeavyTop()
TOP_X0 = TOP.initial_state()


def assert_checkpoint_changes_nothing(loss):
    """The gradient of ``loss(top, checkpoint)`` w.r.t. every parameter of the heavy top, with
    and without checkpointing, to 1e-12 relative (checkpointing is scene-independent: the top
    compiles in a fraction of the vehicle's time)."""
    g_plain = eqx.filter_jit(eqx.filter_grad(loss))(TOP, False)
    g_ckpt = eqx.filter_jit(eqx.filter_grad(loss))(TOP, True)
    for name in ["inertia", "mass", "gravity", "center_of_mass"]:
        a, b = np.asarray(getattr(g_plain, name)), np.asarray(getattr(g_ckpt, name))
        assert np.max(np.abs(a)) > 0, name
        assert np.max(np.abs(a - b)) <= 1e-12 * np.max(np.abs(a)), name


def test_checkpointed_gradient_equals_plain_gradient():
    """1024 steps saved every 8 (a block of 128 saved nodes): the gradient of a loss on the
    whole saved trajectory with blockwise rematerialisation equals the stored-residual one."""

    def loss(top, checkpoint):
        sol = vj.simulate(top, TOP_X0, 0.01, 1024, save_every=8, checkpoint=checkpoint)
        return jnp.mean(jnp.sum(sol.omega**2, axis=-1)) + jnp.mean(sol.R[:, 2, 2])

    assert_checkpoint_changes_nothing(loss)


def test_checkpointed_final_state_gradient_equals_plain_gradient():
    """300 steps saved only at the end: the steps of the one node run as √300 rematerialised
    blocks (17 blocks of 17 steps and 11 more); the gradient equals the stored-residual one."""

    def loss(top, checkpoint):
        sol = vj.simulate(top, TOP_X0, 0.01, 300, save_every=300, checkpoint=checkpoint)
        return jnp.sum(sol.omega[-1] ** 2) + sol.R[-1, 2, 2]

    assert_checkpoint_changes_nothing(loss)
