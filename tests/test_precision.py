"""The engines ask for full-precision matrix products (no TF32 on GPUs for float32 runs). Checked
on any backend in the lowered program: every ``dot_general`` carries precision HIGHEST."""

import jax
import jax.numpy as jnp

import vi_jax as vj


def _dot_precisions(lowered_text):
    dots = [line for line in lowered_text.splitlines() if "dot_general" in line]
    return dots, [d for d in dots if "precision = [HIGHEST, HIGHEST]" not in d]


def test_beam_time_march_requests_highest_precision_in_float32():
    model = vj.models.GeometricallyExactBeam()
    n = 4
    ds = float(model.length) / n
    g0, xi0 = model.initial_state(n)
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731

    def run(xi):
        return vj.multisymplectic.time_march(model, f32(g0), xi0=xi, dt=f32(1e-4), ds=f32(ds), n_steps=3).g

    dots, loose = _dot_precisions(jax.jit(run).lower(f32(xi0)).as_text())
    assert dots and not loose, loose[:3]


def test_simulate_requests_highest_precision_in_float32():
    model = vj.models.HeavyTop()
    x0 = model.initial_state()

    def run(xi):
        return vj.simulate(model, vj.State(jnp.asarray(x0.g, jnp.float32), xi), jnp.float32(0.01), 3, order=2).g

    text = jax.jit(run).lower(jnp.asarray(x0.xi, jnp.float32)).as_text()
    dots, loose = _dot_precisions(text)
    assert not loose, loose[:3]
