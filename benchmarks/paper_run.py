"""The seed 000 reproduction in figures: the paper's run ([0, 500] s, h = 0.01) for both maps and
orders 1 and 2, and the fitted convergence slopes against a tight continuous solution.

    python benchmarks/paper_run.py [--out benchmarks/results/paper_run.json]
"""

import argparse

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from vi_jax import continuous  # noqa: E402




def run_figures(model, x0, tau, order):
    sol = vj.simulate(model, x0, 0.01, 50_000, tau=tau, order=order)
    E, I = np.asarray(sol.energy), np.asarray(sol.kelvin_noether)
    return {
        "q(500)": np.asarray(sol.q[-1]).tolist(),
        "max |dE/E0|": float(np.max(np.abs(E / E[0] - 1))),
        "max |dI|/(|M|+|q||P|)": float(np.max(np.abs(I - I[0]) / np.asarray(sol.kelvin_noether_scale))),
        "max |dI/I0|": float(np.max(np.abs(I / I[0] - 1))),
        "max |R^T R - I|": float(vj.group_constraint_residual(model, sol.R).max()),
        "max Newton residual": float(np.max(np.asarray(sol.newton_residual))),
        "max Newton iterations": int(np.max(np.asarray(sol.newton_iterations))),
    }


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", default="benchmarks/results/paper_run.json")
    args = parser.parse_args()
    from _timing import write_json

    model = vj.models.UnderwaterVehicle()
    x0 = model.initial_state()
    ref = continuous.solve(model, x0, 500.0, rtol=1e-12, atol=1e-12, dt0=0.01)
    q_ref = np.asarray(ref.ys[2][-1])
    result = {"Dopri8 q(500), rtol=atol=1e-12": q_ref.tolist(), "runs": {}, "slopes": {}}
    print(f"Dopri8 reference q(500) = {q_ref}")
    for order in (1, 2):
        for tau in ("cayley", "exp"):
            figures = run_figures(model, x0, tau, order)
            figures["|q(500) - q_ref|"] = float(np.linalg.norm(np.asarray(figures["q(500)"]) - q_ref))
            result["runs"][f"order {order}, {tau}"] = figures
            print(f"order {order}, {tau:6s}: " + ", ".join(f"{k} = {v:.3g}" if isinstance(v, float) else f"{k} = {v}" for k, v in figures.items() if k != "q(500)"))
    T = 20.0
    ref20 = np.asarray(continuous.solve(model, x0, T, rtol=1e-13, atol=1e-13, dt0=0.01).ys[2][-1])
    for order, hs in ((1, (0.04, 0.02, 0.01, 0.005)), (2, (0.2, 0.1, 0.05, 0.025))):
        for tau in ("cayley", "exp"):
            errors = []
            for h in hs:
                n = int(round(T / h))
                errors.append(float(np.linalg.norm(np.asarray(vj.simulate(model, x0, h, n, tau=tau, order=order, save_every=n).q[-1]) - ref20)))
            slope = float(np.polyfit(np.log(hs), np.log(errors), 1)[0])
            result["slopes"][f"order {order}, {tau}"] = {"h": list(hs), "|q(20) - q_ref|": errors, "slope": slope}
            print(f"order {order}, {tau:6s}: |q(20) − q_ref| = {['%.3e' % e for e in errors]}, fitted slope {slope:.3f}")
    write_json(args.out, result)


if __name__ == "__main__":
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    main()
