"""Node energy and Kelvin–Noether quantities (``vi_jax.engine._solution.node_invariants``) on
component arrays of shape (nodes,) against a ``vmap`` of the per-node functions (the form kept
for groups of matrices larger than ``COMPONENTWISE_MATRIX_SIZE``): the compiled call at 65,536
vehicle nodes, timed alternately (median of 7), and the time to trace and compile each form for
the vehicle, the heavy top and a rigid body on SO(6).

    python benchmarks/node_invariants.py
"""

import time
from unittest import mock

from _timing import time_alternately, write_json

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import vi_jax as vj  # noqa: E402
from vi_jax.engine import _solution  # noqa: E402

SCENES = {"vehicle": vj.models.UnderwaterVehicle, "heavy_top": vj.models.HeavyTop, "rigid_body_so6": lambda: vj.models.RigidBody(group=vj.lie.SOn(6))}


def _program(model, sol, size):
    """node_invariants of ``sol``'s nodes as a compiled call, components up to ``size``."""
    args = (sol.g, sol.q, sol.M, sol.P, sol.xi, sol.nu)
    with mock.patch.object(_solution, "COMPONENTWISE_MATRIX_SIZE", size):
        start = time.perf_counter()
        compiled = jax.jit(lambda *a: _solution.node_invariants(model, *a)).lower(*args).compile()
        seconds = time.perf_counter() - start
    return (lambda: compiled(*args)), seconds


def main():
    forms = {"components": 1 << 30, "vmap": 0}
    result = {"trace_and_compile_s": {}, "nodes": 65_536}
    for name, scene in SCENES.items():
        model = scene()
        sol = vj.simulate(model, model.initial_state(), 0.01, 30)
        result["trace_and_compile_s"][name] = {form: _program(model, sol, size)[1] for form, size in forms.items()}
        print(name, {k: round(v, 3) for k, v in result["trace_and_compile_s"][name].items()}, "s to trace and compile")
    model = vj.models.UnderwaterVehicle()
    sol = vj.simulate(model, model.initial_state(), 0.01, result["nodes"] - 1)
    calls = {form: _program(model, sol, size)[0] for form, size in forms.items()}
    result["vehicle_call_s"] = time_alternately(calls)
    print("vehicle, 65,536 nodes:", {k: f"{v * 1e3:.2f} ms" for k, v in result["vehicle_call_s"].items()})
    write_json("benchmarks/results/node_invariants.json", result)


if __name__ == "__main__":
    main()
