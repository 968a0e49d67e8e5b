"""Lagrange top: explicit integrable map against implicit variational integrator, error against
compiled run time.

The same continuous system, ℓ(Ω, Γ) = ½⟨Ω, JΩ + ΩJ⟩ − m g χ·Γ on SO(n) with the Lagrange
mass matrix J = (α/2, …, α/2, 1 − α/2) and χ = |χ|e_n (``vj.models.HeavyTop`` defaults, α = 0.4),
is integrated by

* the generic DEP engine (``vj.simulate``, Cayley, orders 2 and 4: implicit, Newton per step);
* Suris's explicit body-frame map (42)-(43) (``vi_jax.models.suris``): raw (order 1) and with
  half-kick processing (order 2), in Suris's variables M = (𝕀Ω)^, P = m g|χ|Γ, A = e_n;
* diffrax Tsit5 and Dopri8 with adaptive steps (peers),

and compared at t = T with a Dopri8 reference (tolerances 1e-13) of the body-frame equations
Ṁ = [M, Ω] + A∧P, Ṗ = −ΩP. Times: compiled code, warm-up, block_until_ready, median of repeats.

    python benchmarks/tops.py [--n 3] [--T 10] [--repeats 5] [--quick]
"""

import argparse
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import diffrax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from vi_jax.lie import SOn  # noqa: E402
from vi_jax.models import suris  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import time_compiled, write_json  # noqa: E402

ALPHA = 0.4


def lagrange_top(n):
    """The HeavyTop defaults are the Lagrange top with α = 0.4 (J = (0.2, …, 0.2, 0.8))."""
    top = vj.models.HeavyTop() if n == 3 else vj.models.HeavyTop(group=SOn(n))
    return top, top.initial_state()


def to_suris(top, g, xi_or_mu, momentum=False):
    """(M, P): M = (𝕀ξ)^ (or μ^ when ``momentum``), P = m g|χ| gᵀe_n (Suris's A = χ/|χ| = e_n)."""
    G = top.group
    mu = xi_or_mu if momentum else top.inertia @ xi_or_mu
    weight = top.mass * top.gravity * jnp.linalg.norm(top.center_of_mass)
    return G.hat(mu), weight * g[-1]  # gᵀe_n is the last row of g


def vector_field(top):
    """Body-frame Euler–Poincaré equations of the top in Suris's variables (M, P)."""
    G = top.group
    n = G.matrix_size
    A = jnp.eye(n)[-1]
    inertia_inv = jnp.linalg.inv(top.inertia)

    def field(t, y, args):
        M, P = y
        Om = G.hat(inertia_inv @ G.vee(M))
        return M @ Om - Om @ M + (jnp.outer(A, P) - jnp.outer(P, A)), -Om @ P

    return field


def solve_diffrax(field, y0, T, solver, rtol):
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field), solver, 0.0, T, 0.01, y0,
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=rtol), max_steps=1_000_000,
        saveat=diffrax.SaveAt(t1=True),
    )
    return jax.tree.map(lambda x: x[-1], sol.ys), sol.stats["num_steps"]


def error(y, ref):
    """max |ΔM|, |ΔP| relative to max(|M|, |P|) of the reference."""
    scale = max(float(jnp.max(jnp.abs(ref[0]))), float(jnp.max(jnp.abs(ref[1]))))
    return max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(y, ref)) / scale


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--n", type=int, default=3, help="SO(n); n = 3 uses the SO3 class")
    parser.add_argument("--T", type=float, default=10.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="three step sizes, fewer tolerances")
    parser.add_argument("--out", default="benchmarks/results/tops.json")
    parser.add_argument("--png", default="benchmarks/results/tops.png")
    args = parser.parse_args()

    top, x0 = lagrange_top(args.n)
    M0, P0 = to_suris(top, x0.g, x0.xi)
    A = jnp.eye(args.n)[-1]
    field = vector_field(top)
    consistency = jax.tree.map(
        lambda a, b: float(jnp.max(jnp.abs(a - b))),
        field(0.0, (M0, P0), None), suris.lagrange_top_body_frame_vector_field(M0, P0, A, ALPHA),
    )
    print(f"vector field vs suris.lagrange_top_body_frame_vector_field: {max(consistency):.1e}")
    ref, _ = jax.jit(lambda y: solve_diffrax(field, y, args.T, diffrax.Dopri8(), 1e-13))((M0, P0))

    steps = [200, 800, 3200] if args.quick else [200, 400, 800, 1600, 3200, 6400, 12800, 25600]
    tolerances = [1e-4, 1e-8] if args.quick else [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12]
    methods = {}

    def record(method, setting, fn, extract):
        first, median, out = time_compiled(fn, repeats=args.repeats)
        err = error(extract(out), ref)
        row = dict(setting=setting, compile_and_first_s=first, median_s=median, error=err)
        methods.setdefault(method, []).append(row)
        print(f"{method:32s} {setting:>14s} {first:9.3f} {median:11.5f} {err:11.3e}")

    print(f"{'method':32s} {'setting':>14s} {'compile+1st':>9s} {'median [s]':>11s} {'rel. error':>11s}")
    for N in steps:
        h = args.T / N
        for order in (2, 4):
            sim = jax.jit(
                lambda order=order, N=N, h=h: vj.simulate(top, x0, h, N, order=order, save_every=N, throw=False)
            )
            record(f"DEP-Cayley order {order} (implicit)", f"N={N}", sim,
                   lambda s: to_suris(top, s.g[-1], s.M[-1], momentum=True))
        raw = jax.jit(lambda N=N, h=h: suris.lagrange_top_body_frame(M0, P0, A, ALPHA, h, N))
        record("Suris (42) raw (explicit)", f"N={N}", raw, lambda y: (y[0][-1], y[1][-1]))
        processed = jax.jit(lambda N=N, h=h: suris.lagrange_top_body_frame_processed(M0, P0, A, ALPHA, h, N))
        record("Suris (42) half-kick (explicit)", f"N={N}", processed, lambda y: (y[0][-1], y[1][-1]))
    peers = (("diffrax Tsit5 (adaptive)", diffrax.Tsit5()), ("diffrax Dopri8 (adaptive)", diffrax.Dopri8()))
    for name, solver in peers:
        run = jax.jit(lambda rtol, solver=solver: solve_diffrax(field, (M0, P0), args.T, solver, rtol))
        for rtol in tolerances:
            record(name, f"rtol={rtol:.0e}", lambda rtol=rtol, run=run: run(jnp.asarray(rtol)), lambda y: y[0])

    slopes = {}
    for method, rows in methods.items():
        if rows[0]["setting"].startswith("N="):
            N = np.array([int(r["setting"][2:]) for r in rows])[-4:]  # the four finest steps
            err = np.array([r["error"] for r in rows])[-4:]
            slopes[method] = float(-np.polyfit(np.log(N), np.log(err), 1)[0])
    for method, slope in slopes.items():
        print(f"observed order of {method} (up to four finest steps): {slope:.2f}")
    write_json(args.out, dict(
        system=f"Lagrange top on SO({args.n}), HeavyTop defaults (α = {ALPHA}, m g|χ| = "
        f"{float(top.mass * top.gravity * jnp.linalg.norm(top.center_of_mass)):g}), T = {args.T}",
        reference="diffrax Dopri8, rtol = atol = 1e-13", error="max(|ΔM|, |ΔP|) / max(|M|, |P|) at T",
        devices=str(jax.devices()), observed_orders_finest_steps=slopes, methods=methods,
    ))
    plot(methods, args)


def plot(methods, args):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5))
    styles = {"DEP": "o-", "Suris": "s--", "diffrax": "^:"}
    for method, rows in methods.items():
        style = next(v for k, v in styles.items() if method.startswith(k))
        ax.loglog([r["median_s"] for r in rows], [r["error"] for r in rows], style, ms=4, label=method)
    ax.set_xlabel("compiled run time [s] (median)")
    ax.set_ylabel("relative error of (M, P) at T")
    title = f"Lagrange top on SO({args.n}), T = {args.T:g}: explicit integrable vs implicit variational"
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    Path(args.png).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.png, dpi=130)
    print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
