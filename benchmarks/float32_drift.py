"""Where float32 round-off drifts (issue 6): the heavy top with Cayley order 2, h = 0.01 (the
long runs of benchmarks/stability.py), in float32, with and without re-orthonormalising the
attitude after every step (one Newton–Schulz step R ← R(3I − RᵀR)/2, which removes the
component of the round-off that leaves SO(3) and nothing else to first order).

If the linear drift of the energy and of the Kelvin–Noether quantity comes from R leaving SO(3)
(the one multiplicative accumulation, R ← RΛ), the projected run stops drifting; the only
additive accumulation (the vehicle's q ← q + hRν) does not exist here, so compensated (Kahan)
summation has nothing to act on.

    python benchmarks/float32_drift.py [--steps 1000000] [--out benchmarks/results/float32_drift.json]
"""

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
N_SAVED = 200


def run(n_steps, project):
    """In this process's precision: max |E/E₀ − 1|, max |ΔKN|/scale and ‖RᵀR − I‖ at N_SAVED nodes."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import numpy as np

    import vi_jax as vj
    from vi_jax.discrete._dep import dep_step, inverse_legendre, legendre_initial_state
    from vi_jax.lie import difference_map

    sys.path.insert(0, str(HERE))
    import _stability_cases as cases

    p = {k: jnp.asarray(v) for k, v in cases.default_params("heavy_top").items()}
    p["omega"] = p["omega"] * 6.01
    system, x0 = cases.build("heavy_top", p)
    tau, h = difference_map("cayley"), jnp.asarray(0.01, x0.g.dtype)
    rtol = 64 * float(jnp.finfo(x0.g.dtype).eps)
    eye = jnp.eye(3, dtype=x0.g.dtype)

    def step(state, _):
        state, _ = dep_step(system, tau, "trapezoid", h, state, rtol=rtol, max_iterations=20)
        if project:
            g = state.g
            state = eqx.tree_at(lambda s: s.g, state, 0.5 * g @ (3 * eye - g.T @ g))
        return state, None

    def node(state, _):
        state, _ = jax.lax.scan(step, state, None, length=n_steps // N_SAVED)
        return state, (state.g, state.M, state.z)

    @jax.jit
    def trajectory():
        state = legendre_initial_state(system, x0.g, x0.xi)
        _, (g, M, z) = jax.lax.scan(node, state, None, length=N_SAVED)
        g, M, z = (jnp.concatenate([a[None], b]) for a, b in ((state.g, g), (state.M, M), (state.z, z)))

        def diagnostics(g, M, z):
            xi, _ = inverse_legendre(system, g, None, M, None, z, rtol=rtol, max_iterations=20)
            a = system.body_advected(g)
            return system.energy(xi, None, None, a), vj.kelvin_noether(system, g, None, M, None)

        energy, kn = jax.vmap(diagnostics)(g, M, z)
        return energy, kn, jnp.linalg.norm(M[0]), vj.group_constraint_residual(system, g)

    energy, kn, scale, residual = (np.asarray(x, np.float64) for x in trajectory())
    return dict(
        dtype=str(x0.g.dtype), project=project, n_steps=n_steps,
        energy_error=float(np.max(np.abs(energy / energy[0] - 1))),
        kelvin_noether_error=float(np.max(np.abs(kn - kn[0])) / scale),
        group_residual=float(np.max(residual)),
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--out", type=Path, default=HERE / "results" / "float32_drift.json")
    args = parser.parse_args()
    rows = []
    for x64 in ("1", "0"):
        for project in ("0", "1"):
            env = dict(os.environ, JAX_ENABLE_X64=x64)
            out = subprocess.run([sys.executable, __file__, "--worker", str(args.steps), project], env=env,
                                 check=True, capture_output=True, text=True)
            row = json.loads(out.stdout.strip().splitlines()[-1])
            rows.append(row)
            print(f"{row['dtype']:8s} {'projected' if row['project'] else 'plain':9s} {row['n_steps']:>9d} steps: "
                  f"energy {row['energy_error']:.2e}, Kelvin–Noether/scale {row['kelvin_noether_error']:.2e}, "
                  f"‖RᵀR − I‖ {row['group_residual']:.2e}", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--worker"]:
        print(json.dumps(run(int(sys.argv[2]), sys.argv[3] == "1")))
    else:
        main()
