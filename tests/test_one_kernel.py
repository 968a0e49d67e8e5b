"""One-kernel regions (``vi_jax._one_kernel``): the same values, derivatives and batching as
their body; XLA:CPU gets the region as a call it compiles into one kernel when the region holds
only operations its one-kernel emitter knows, and a plain call otherwise."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vi_jax._one_kernel import one_kernel

A = jnp.asarray([[0.9, 0.2, 0.0], [-0.1, 0.8, 0.3], [0.0, 0.2, 0.7]])


def one_kernel_calls(compiled) -> int:
    """Regions of a compiled program that XLA:CPU compiles into one kernel (not counting the
    tiny loops XLA marks so itself)."""
    return len(re.findall(r'to_apply=%one_kernel[\w.]*, frontend_attributes=\{[^}]*xla_cpu_small_call="true"', compiled.as_text()))


def _marked(fn, *args):
    return one_kernel_calls(jax.jit(fn).lower(*args).compile())


def _elementwise_loop(x, y, c):
    """A loop of elementwise steps closing over ``c`` (a tracer under ``jit``: an input of the region)."""

    def step(_, carry):
        x, y = carry
        return jnp.sin(x) * y + c, jnp.cos(y) * x - 0.5 * c

    return jax.lax.fori_loop(0, 7, step, (x, y))


def _products_loop(x, y, c):
    return jax.lax.fori_loop(0, 7, lambda _, xy: (xy[0] @ A + c, xy[1] @ A.T), (x, y))


def _solve(x, y, c):
    return jnp.linalg.solve(A + c * jnp.eye(3), x), y


@pytest.mark.parametrize("body, kernel", [(_elementwise_loop, True), (_products_loop, False), (_solve, False)])
def test_region_equals_its_body_in_value_derivatives_and_batches(body, kernel):
    """Values, forward and reverse derivatives and ``vmap`` of the region equal those of its body
    (the same operations: to round-off, a few ε of the values' scale); a loop of elementwise
    steps is marked for one kernel, matrix products and LAPACK solves are not (XLA:CPU's
    one-kernel emitter has neither) and run as a plain call."""
    x, y = jnp.linspace(0.1, 0.9, 3), jnp.linspace(-0.5, 0.4, 3)
    region = one_kernel(lambda x, y, c: body(x, y, c))
    ulp = 8 * np.finfo(np.float64).eps

    def close(a, b):
        for u, v in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
            np.testing.assert_allclose(u, v, rtol=ulp, atol=ulp * float(jnp.max(jnp.abs(v))))

    close(jax.jit(region)(x, y, 0.3), body(x, y, 0.3))
    close(jax.jvp(lambda c: region(x, y, c), (0.3,), (1.0,)), jax.jvp(lambda c: body(x, y, c), (0.3,), (1.0,)))
    loss = lambda f: lambda x, c: jnp.sum(f(x, y, c)[0] ** 2)  # noqa: E731
    close(jax.grad(loss(region), argnums=(0, 1))(x, 0.3), jax.grad(loss(body), argnums=(0, 1))(x, 0.3))
    xs = x + jnp.linspace(0.0, 0.2, 4)[:, None]
    close(jax.jit(jax.vmap(region, in_axes=(0, None, None)))(xs, y, 0.3), jax.vmap(body, in_axes=(0, None, None))(xs, y, 0.3))
    assert _marked(region, x, y, 0.3) == int(kernel)
    assert _marked(jax.vmap(region, in_axes=(0, None, None)), xs, y, 0.3) == int(kernel)


def test_region_with_side_effects_runs_as_its_body():
    """A callback inside the region: no region (XLA:CPU's one kernel cannot call back), the
    callback runs."""
    seen = []

    def body(x):
        jax.debug.callback(lambda v: seen.append(float(v)), x[0])
        return (x * 2,)

    region = one_kernel(body)
    assert "vi_jax_one_kernel" not in str(jax.make_jaxpr(region)(jnp.ones(2)))
    np.testing.assert_array_equal(jax.jit(region)(jnp.ones(2))[0], 2.0)
    assert seen == [1.0]
