"""Compiled programs kept between concrete calls (``vi_jax/engine/_kept_programs.py``): reused for
inputs of the same signature under the same configuration, compiled anew otherwise, dropped by
``jax.clear_caches()``; a concrete ensemble run in groups on cores lowers its program once."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vi_jax as vj
from vi_jax.engine import _kept_programs, _member_groups
from vi_jax.engine._kept_programs import compiled_program


class Lowering:
    """A jitted program that counts its lowerings."""

    def __init__(self):
        self.program = eqx.filter_jit(lambda x, scale, *, shift: scale * x + shift)
        self.lowered = 0

    def lower(self, *args, **kwargs):
        self.lowered += 1
        return self.program.lower(*args, **kwargs)


pytestmark = pytest.mark.usefixtures("fresh_programs")  # no kept programs before or after


def test_same_signature_runs_the_kept_program():
    spy = Lowering()
    first = compiled_program(spy, jnp.ones(3), 2.0, shift=1)
    again = compiled_program(spy, jnp.arange(3.0), 2.0, shift=1)  # other values, same signature
    assert again is first and spy.lowered == 1
    np.testing.assert_array_equal(np.asarray(again(jnp.arange(3.0), 2.0, shift=1)), [1.0, 3.0, 5.0])


@pytest.mark.parametrize(
    "args, kwargs",
    [
        ((jnp.ones(4), 2.0), dict(shift=1)),  # shape
        ((jnp.ones(3, jnp.int32), 2.0), dict(shift=1)),  # dtype
        ((jnp.ones(3), 2.0), dict(shift=1.0)),  # a static value's type (1.0 == 1)
        ((jnp.ones(3), 3.0), dict(shift=1)),  # a static value
        ((np.ones(3), 2.0), dict(shift=1)),  # a NumPy array: another placement
    ],
    ids=["shape", "dtype", "static type", "static value", "numpy input"],
)
def test_another_signature_compiles_anew(args, kwargs):
    spy = Lowering()
    first = compiled_program(spy, jnp.ones(3), 2.0, shift=1)
    other = compiled_program(spy, *args, **kwargs)
    assert other is not first and spy.lowered == 2
    np.testing.assert_allclose(np.asarray(other(*args, **kwargs)), args[1] * np.asarray(args[0]) + kwargs["shift"])


def test_configuration_and_clear_caches():
    """Another trace context (a precision context, as ``vj.ensemble`` enters) compiles anew;
    ``jax.clear_caches()`` drops every kept program, as it drops ``jit``'s."""
    spy = Lowering()
    first = compiled_program(spy, jnp.ones(3), 2.0, shift=1)
    with jax.default_matmul_precision("highest"):
        assert compiled_program(spy, jnp.ones(3), 2.0, shift=1) is not first
    assert compiled_program(spy, jnp.ones(3), 2.0, shift=1) is first
    jax.clear_caches()
    assert compiled_program(spy, jnp.ones(3), 2.0, shift=1) is not first
    assert spy.lowered == 3


def test_least_recently_used_dropped(monkeypatch):
    monkeypatch.setattr(_kept_programs, "KEPT", 2)
    spy = Lowering()
    kept = [compiled_program(spy, jnp.ones(n), 2.0, shift=1) for n in (1, 2)]
    compiled_program(spy, jnp.ones(1), 2.0, shift=1)  # n = 1 used last: n = 2 goes next
    compiled_program(spy, jnp.ones(3), 2.0, shift=1)
    assert compiled_program(spy, jnp.ones(1), 2.0, shift=1) is kept[0]
    assert compiled_program(spy, jnp.ones(2), 2.0, shift=1) is not kept[1]
    assert spy.lowered == 4


def test_traced_inputs_have_no_signature():
    signatures = []
    jax.jit(lambda x: signatures.append(_kept_programs._signature(Lowering(), (x, 2.0), dict(shift=1))) or x)(jnp.ones(3))
    assert signatures == [None]


def test_ensemble_groups_lower_once(monkeypatch):
    """Two concrete ensemble calls in groups on two "cores" with other initial states: one
    program lowered, kept, and equal results to the groups' first run on the same states."""
    monkeypatch.setattr(_member_groups, "cores", lambda: 2)
    monkeypatch.setattr(_member_groups, "MIN_GROUP", 2)
    lowered = []
    real = _kept_programs.compiled_program

    def counting(program, *args, **kwargs):
        original = program.lower
        program.lower = lambda *a, **k: lowered.append(1) or original(*a, **k)
        try:
            return real(program, *args, **kwargs)
        finally:
            program.lower = original

    monkeypatch.setattr(_member_groups, "compiled_program", counting)
    model = vj.models.HeavyTop()
    x0 = model.initial_state()
    states = [vj.vary(x0, xi=np.asarray(x0.xi) + 0.05 * np.random.default_rng(k).normal(size=(6, 3))) for k in (0, 1)]
    run = lambda s: vj.ensemble(model, s, 0.005, 40, save_every=10)  # noqa: E731
    first = [run(s) for s in states]
    assert len(lowered) == 1
    again = run(states[0])
    np.testing.assert_array_equal(np.asarray(again.g), np.asarray(first[0].g))
    assert not np.array_equal(np.asarray(first[1].g), np.asarray(first[0].g))
