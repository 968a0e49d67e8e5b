"""What XLA:CPU makes of the generated batched step: a census of the optimised HLO of one step
(the body of the innermost step loop of ``vj.ensemble``, 64 members per chunk for every scene,
Cayley), with
no timing. Per scene: the elementwise operations per member (fused computations counted with
the operations XLA copied into them, so the count exceeds the jaxpr's where XLA duplicates
cheap subexpressions), and the thunks XLA:CPU dispatches one by one with its default flags:
loop fusions, conditionals (the step's fusion boundaries) and the copies their branches make.
Where Newton's factors are carried from step to step (the order-2 scenes), a step that takes a
Jacobian is counted (the refresh conditional's taken branch is its last one, as for the
boundaries). Each program is compiled twice: with XLA's default options (as under a caller's
``jit``) and with ``ENSEMBLE_OPTIONS`` (as a concrete call on the CPU compiles it). The last
row is the peer: the vehicle's hand-written batched step (``_hand_vehicle_kernel.py``, order 1,
chunks of 64 members).

    python benchmarks/generated_step_hlo.py
"""

import collections
import re

from _timing import write_config_json

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

import vi_jax as vj  # noqa: E402
from _generated import perturbed_states  # noqa: E402
from _hand_vehicle_kernel import hand_kernel_ensemble  # noqa: E402
from vi_jax.engine import _ensemble  # noqa: E402
from vi_jax.engine._compile_options import ENSEMBLE_OPTIONS  # noqa: E402

MEMBERS, STEPS = 1024, 1000
CASES = [("rigid_body", vj.models.RigidBody, 0.01, 1), ("rigid_body", vj.models.RigidBody, 0.01, 2),
         ("heavy_top", vj.models.HeavyTop, 0.005, 1), ("heavy_top", vj.models.HeavyTop, 0.005, 2),
         ("vehicle", vj.models.UnderwaterVehicle, 0.01, 1), ("vehicle", vj.models.UnderwaterVehicle, 0.01, 2),
         ("vehicle_hand", vj.models.UnderwaterVehicle, 0.01, 1)]
NOT_COUNTED = {"parameter", "get-tuple-element", "tuple", "constant", "bitcast", "broadcast", "reshape"}


def computations(hlo):
    """Computation name → its instruction lines."""
    out, current = {}, None
    for line in hlo.splitlines():
        head = re.match(r"^(?:ENTRY )?%(\S+) ", line)
        if head and line.rstrip().endswith("{"):
            current = out[head.group(1)] = []
        elif current is not None and line.strip() != "}":
            current.append(line)
    return out


def opcode(line):
    m = re.match(r"\s*(?:ROOT )?%\S+ = .*? ([a-z][a-z0-9-]*)\(", line)
    return m.group(1) if m else None


def census(comps, name, taken_branch=False):
    """Operations and thunks of computation ``name``: fusions counted with their contents, a
    conditional with its taken branch (the last one: the identity branch of a boundary, the
    fallback's ``common`` path is the first and has no while loop)."""
    count = collections.Counter()
    for line in comps[name]:
        op = opcode(line)
        if op == "fusion":
            count["fusions"] += 1
            inner = census(comps, re.search(r"calls=%([^,\s]+)", line).group(1))
            count["operations"] += inner["operations"] + inner["copies"]
        elif op == "conditional":
            count["conditionals"] += 1
            branches = [b.strip().lstrip("%") for b in re.search(r"branch_computations=\{([^}]*)\}", line).group(1).split(",")]
            inner = census(comps, branches[-1] if "while(" not in "".join(comps[branches[-1]]) else branches[0])
            count.update(inner)
        elif op == "copy":
            count["copies"] += 1
        elif op == "while":
            count["loops"] += 1
        elif op is not None and op not in NOT_COUNTED:
            count["operations"] += 1
    return count


def step_body(comps):
    """The innermost step loop's body: the while body with the most fusions, counted with those
    of its conditionals' counted branches (a loop nested in it is not counted: the loops over
    saved nodes hold few fusions of their own)."""
    bodies = []
    for lines in comps.values():
        for line in lines:
            m = re.search(r" while\(.*body=%([^,\s]+)", line)
            if m:
                bodies.append((census(comps, m.group(1))["fusions"], m.group(1)))
    return max(bodies)[1]


def main():
    rows = []
    for name, scene, h, order in CASES:
        model = scene()
        states = perturbed_states(model.initial_state(), MEMBERS)
        if name == "vehicle_hand":
            run = jax.jit(lambda m, s, h: hand_kernel_ensemble(m, s, h, STEPS, save_every=STEPS).g[:, -1])
        else:
            run = jax.jit(lambda m, s, h, order=order: vj.ensemble(m, s, h, STEPS, order=order, save_every=STEPS, method="batched", throw=False).g[:, -1])
        lowered = run.lower(model, states, jnp.asarray(h))
        comps = computations(lowered.compile().as_text())
        count = census(comps, step_body(comps))
        thunks = count["fusions"] + count["conditionals"] + count["copies"]
        tuned = computations(lowered.compile(compiler_options=ENSEMBLE_OPTIONS).as_text())
        tuned = census(tuned, step_body(tuned))
        tuned_thunks = tuned["fusions"] + tuned["conditionals"] + tuned["copies"]
        rows.append(dict(scene=name, order=order, operations=count["operations"], fusions=count["fusions"],
                         conditionals=count["conditionals"], copies=count["copies"], thunks=thunks,
                         with_ensemble_options=dict(operations=tuned["operations"], copies=tuned["copies"], thunks=tuned_thunks)))
        print(f"{name:10s} order {order}: {count['operations']:6d} elementwise operations per member-step, "
              f"{thunks} thunks ({count['fusions']} fusions, {count['conditionals']} conditionals, {count['copies']} copies); "
              f"with ENSEMBLE_OPTIONS {tuned_thunks} thunks ({tuned['copies']} copies)", flush=True)
    write_config_json("generated_step_hlo", False, members_per_chunk=_ensemble.CHUNK, rows=rows)


if __name__ == "__main__":
    main()
