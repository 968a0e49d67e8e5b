"""SO(n)'s exponential: the scaled Taylor polynomial of ``vi_jax.lie.SOn.exp`` against
``jax.scipy.linalg.expm`` (Padé with scaling and squaring, what SOn used before), same log.

Per n, both peers in one process: compile time of exp with the derivatives the engine and the
zero test take (value, gradient and a Hessian-vector product of Σexp + Σdexp⁻¹ at x = 0), and an
SO(n) free rigid body with τ = exp, order 2: first call (trace + compile + run) and the median
compiled step of a 1000-step run.

    python benchmarks/son_exp.py [--fast-loops]    # ≈ 2 min; writes benchmarks/results/son_exp[_fast_loops].json

``--fast-loops`` calls ``vi_jax.enable_fast_cpu_loops()`` first (the XLA:CPU loop option).
"""

import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import vi_jax as vj  # noqa: E402
from vi_jax.lie import SOn  # noqa: E402

from _timing import fast_loops_from_argv, time_compiled, write_config_json  # noqa: E402

N_STEPS = 1000


class PadeSOn(SOn):
    """SO(n) with the generic Padé exponential (the peer)."""

    def exp(self, x):
        return jax.scipy.linalg.expm(self.hat(x))


def derivative_compile_s(group):
    tau = vj.lie.Exp()
    f = lambda x: jnp.sum(tau.tau(group, x)) + jnp.sum(tau.dtau_inv(group, x))  # noqa: E731
    hvp = lambda x: jax.jvp(jax.grad(f), (x,), (jnp.ones_like(x),))[1]  # noqa: E731
    start = time.perf_counter()
    jax.block_until_ready(jax.jit(lambda x: (f(x), jax.grad(f)(x), hvp(x)))(jnp.zeros(group.dim)))
    return time.perf_counter() - start


def rigid_body(group, n):
    system = vj.models.RigidBody(group=group, mass_matrix=np.linspace(0.6, 0.1, n))
    x0 = system.initial_state()
    first, median, _ = time_compiled(lambda: vj.simulate(system, x0, 0.01, N_STEPS, tau="exp", order=2).g)
    return dict(first_call_s=first, us_per_step=median / N_STEPS * 1e6)


def main():
    fast_loops = fast_loops_from_argv()
    rows = []
    for n in (3, 4, 5):
        row = dict(n=n)
        for name, group in (("scaled Taylor (SOn.exp)", SOn(n)), ("jax.scipy.linalg.expm", PadeSOn(n))):
            row[name] = dict(derivatives_compile_s=derivative_compile_s(group), rigid_body=rigid_body(group, n))
            r = row[name]
            print(f"SO({n}) {name:24s}: derivatives compile {r['derivatives_compile_s']:5.2f} s; rigid body first call "
                  f"{r['rigid_body']['first_call_s']:5.2f} s, {r['rigid_body']['us_per_step']:6.1f} us/step")
        rows.append(row)
    write_config_json("son_exp", fast_loops, n_steps=N_STEPS, rows=rows)


if __name__ == "__main__":
    main()
