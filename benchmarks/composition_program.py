"""Orders 2, 4 and 6 of ``vj.simulate`` on concrete inputs as one compiled program: the
trapezoid compositions' sub-step fractions as traced data (``TracedComposition``, a loop of
traced length over them) against static fractions (one program per order, the previous rule).

Both peers in one process, per scene: the first call of orders 2, 4, 6 in turn (trace +
compile + run; the traced peer compiles once) and the median compiled step of each order over
1000 steps (for order 2: a loop of one sub-step against the plain step).

    python benchmarks/composition_program.py [--fast-loops]   # ≈ 3 min; writes benchmarks/results/composition_program[_fast_loops].json

``--fast-loops`` calls ``vi_jax.enable_fast_cpu_loops()`` first (the XLA:CPU loop option).
"""

import jax
import jax.numpy as jnp

jax.config.update("jax_enable_x64", True)

import vi_jax as vj  # noqa: E402
from vi_jax.discrete import composition_coefficients  # noqa: E402
from vi_jax import _saved_nodes  # noqa: E402
from vi_jax.engine import _simulate  # noqa: E402
from vi_jax.engine._compile_options import single_trajectory_jit  # noqa: E402
from vi_jax.engine._advance import traced_composition  # noqa: E402
from vi_jax.lie import Cayley  # noqa: E402

from _timing import fast_loops_from_argv, time_compiled, write_config_json  # noqa: E402

N_STEPS = 1000
# The concrete call's loop and node diagnostics as one program (vj.simulate runs them as two).
_LOOP_PROGRAM = single_trajectory_jit(_simulate.loop_program)


def run(system, x0, order, traced):
    rule, gammas = composition_coefficients(order)
    count = lambda n: jnp.asarray(n, jnp.int32)  # noqa: E731
    return _LOOP_PROGRAM(
        system, x0, jnp.asarray(0.01), count(N_STEPS), count(1), capacity=_saved_nodes.saved_capacity(N_STEPS), tau=Cayley(),
        rule=rule, gammas=traced_composition(gammas) if traced else gammas, rtol=_simulate._default_rtol(jnp.float64), max_iter=20,
    ).g


def main():
    fast_loops = fast_loops_from_argv()
    rows = []
    for name, system in (("UnderwaterVehicle", vj.models.UnderwaterVehicle()), ("HeavyTop", vj.models.HeavyTop())):
        x0 = system.initial_state()
        row = dict(scene=name)
        for peer, traced in (("static fractions", False), ("traced fractions", True)):
            first, us = {}, {}
            for order in (2, 4, 6):
                first[order], median, _ = time_compiled(lambda: run(system, x0, order, traced))
                us[order] = median / N_STEPS * 1e6
            row[peer] = dict(first_call_s=first, us_per_step=us)
            print(f"{name:17s} {peer}: first calls (orders 2, 4, 6) " + ", ".join(f"{v:.2f}" for v in first.values())
                  + " s; " + ", ".join(f"{v:.2f}" for v in us.values()) + " us/step")
        rows.append(row)
    write_config_json("composition_program", fast_loops, n_steps=N_STEPS, rows=rows)


if __name__ == "__main__":
    main()
