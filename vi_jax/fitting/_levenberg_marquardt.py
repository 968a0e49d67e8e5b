"""Levenberg–Marquardt as an optax gradient transformation (damped Gauss–Newton on whitened residuals)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import optax


class LevenbergMarquardtState(eqx.Module):
    damping: jax.Array


def levenberg_marquardt(damping=1e-3, increase=4.0, decrease=3.0) -> optax.GradientTransformationExtraArgs:
    """Levenberg–Marquardt as an optax transformation. ``update`` needs the extra arguments
    ``residuals`` r and ``jacobian`` J at ``params`` and ``value_fn`` (½Σr²/Σw); it proposes
    δ = −(JᵀJ + λ·diag JᵀJ)⁻¹Jᵀr and returns it if it lowers ``value_fn``, else 0 with a larger
    λ (a rejected step costs one evaluation)."""

    def init(params):
        return LevenbergMarquardtState(jnp.asarray(damping, jnp.result_type(params)))

    def update(updates, state, params, *, residuals, jacobian, value_fn, value, **extra):
        del updates, extra
        A = jacobian.T @ jacobian
        g = jacobian.T @ residuals
        scale = jnp.diag(A) + 1e-12 * jnp.max(jnp.diag(A))
        step = -jnp.linalg.solve(A + state.damping * jnp.diag(scale), g)
        accept = value_fn(params + step) < value
        new = jnp.where(accept, state.damping / decrease, state.damping * increase)
        return jnp.where(accept, step, 0.0), LevenbergMarquardtState(new)

    return optax.GradientTransformationExtraArgs(init, update)
