"""The timed programs of the error-against-run-time study (``vi_jax.studies.work_precision``):
vi_jax's schemes and diffrax's solvers on the same continuous equations, compiled ahead of time,
warmed up once and timed in interleaved rounds."""

import dataclasses
import math
import time
from typing import ClassVar

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from .. import continuous
from ..engine import simulate

MAX_STEPS = 50_000_000
ADAPTIVE = {"tsit5": diffrax.Tsit5, "dopri5": diffrax.Dopri5, "dopri8": diffrax.Dopri8, "kvaerno5": diffrax.Kvaerno5}
SOLVER_NAMES = {"tsit5": "Tsit5", "dopri5": "Dopri5", "dopri8": "Dopri8", "kvaerno5": "Kvaerno5", "rk4": "RK4"}
FIELDS = {"vi_jax": continuous.vector_field}  # diffrax's vector fields by name (benchmarks add hand-written ones)


class RK4(diffrax.AbstractERK):
    """The classical fourth-order Runge–Kutta method (diffrax 0.7 ships none); fixed steps only."""

    tableau: ClassVar[diffrax.ButcherTableau] = diffrax.ButcherTableau(
        a_lower=(np.array([0.5]), np.array([0.0, 0.5]), np.array([0.0, 0.0, 1.0])),
        b_sol=np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6]),
        b_error=np.zeros(4),
        c=np.array([0.5, 0.5, 1.0]),
    )
    interpolation_cls: ClassVar = diffrax.ThirdOrderHermitePolynomialInterpolation.from_k

    def order(self, terms):
        return 4


def _vi_jax_program(tau, order, n_steps, n_saved, whole_solution):
    """``vj.simulate`` returning its whole :class:`Solution` (``whole_solution``: the long-horizon
    runs, whose invariants are the scheme's own diagnostics) or, like the diffrax programs, only
    the nodes' state (g, ξ, q, ν) and result codes (the error studies: XLA then drops the energy
    and Kelvin–Noether diagnostics, which diffrax's programs do not compute either)."""
    save_every = n_steps // n_saved

    def run(system, x0, h):
        if tau == "splitting":
            sol = simulate(system, x0, h, n_steps, scheme="splitting", order=order, save_every=save_every, throw=False)
        else:
            sol = simulate(system, x0, h, n_steps, tau=tau, order=order, save_every=save_every, throw=False)
        return sol if whole_solution else ((sol.g, sol.xi, sol.q, sol.nu), sol.result)

    return jax.jit(run)


def _diffrax_program(solver, n_saved, field):
    """diffrax on the continuous EP field ``FIELDS[field]``; ``control`` is rtol = atol (adaptive,
    PID controller with diffrax's default coefficients) or the step (RK4, constant step size)."""

    def run(system, y0, t1, control):
        if solver == "rk4":
            method, controller, dt0 = RK4(), diffrax.ConstantStepSize(), control
        else:
            method, controller, dt0 = ADAPTIVE[solver](), diffrax.PIDController(rtol=control, atol=control), None
        interior = jnp.linspace(0.0, t1, n_saved + 1)[1:-1] if n_saved > 1 else None
        sol = diffrax.diffeqsolve(
            FIELDS[field](system), method, 0.0, t1, dt0, y0, stepsize_controller=controller,
            saveat=diffrax.SaveAt(t0=True, t1=True, ts=interior), max_steps=MAX_STEPS, throw=False,
        )
        return sol.ys, sol.stats["num_steps"], sol.result == diffrax.RESULTS.successful

    return jax.jit(run)


@dataclasses.dataclass
class Run:
    """One timed configuration: ``program`` (a key into the compiled-program cache and its
    builder) applied to ``args``; measurements are filled in by :func:`measure`."""

    section: str  # "work_precision" or "long_horizon"
    system: str
    peer: str
    setting: dict
    key: tuple
    build: object
    args: tuple
    compile_s: float = math.nan
    first_s: float = math.nan
    samples: list = dataclasses.field(default_factory=list)
    output: object = None

    @property
    def label(self):
        return f"{self.system}: {self.peer} {_setting_text(self.setting)}"


def _setting_text(setting):
    return ", ".join(f"{k}={v}" if isinstance(v, int) else f"{k}={v:g}" for k, v in setting.items())


def _vi_jax_peer(tau, order):
    return f"vi_jax {tau} order {order}"


def _diffrax_peer(solver, field="vi_jax"):
    how = "fixed step" if solver == "rk4" else "PID"
    return f"diffrax {SOLVER_NAMES[solver]} ({how}" + ("" if field == "vi_jax" else f", {field} field") + ")"


def _vi_jax_run(section, name, system, x0, tau, order, T, n_steps, n_saved):
    return Run(
        section, name, _vi_jax_peer(tau, order), {"n_steps": n_steps, "h": T / n_steps},
        ("vi_jax", type(system).__name__, tau, order, n_steps, n_saved, section),
        lambda: _vi_jax_program(tau, order, n_steps, n_saved, section == "long_horizon"), (system, x0, jnp.asarray(T / n_steps)),
    )


def _diffrax_run(section, name, system, x0, solver, T, control, n_saved, field="vi_jax"):
    setting = {"n_steps": round(T / control), "h": control} if solver == "rk4" else {"rtol": control}
    return Run(
        section, name, _diffrax_peer(solver, field), setting, ("diffrax", type(system).__name__, solver, n_saved, field),
        lambda: _diffrax_program(solver, n_saved, field),
        (system, continuous.initial_state(system, x0), jnp.asarray(T), jnp.asarray(control)),
    )


def _compiled(cache, run):
    """The compiled program of ``run`` (compiled once per key; compile time recorded)."""
    if run.key not in cache:
        start = time.perf_counter()
        exe = run.build().lower(*run.args).compile()
        cache[run.key] = (exe, time.perf_counter() - start)
    return cache[run.key]


def measure(runs, repeats, *, progress=True, cache=None):
    """Compile, warm up, then time every run in ``repeats`` interleaved rounds (in place)."""
    from tqdm.auto import tqdm

    cache = {} if cache is None else cache
    with tqdm(total=len(runs) * (1 + repeats), desc="configurations", unit="run", disable=not progress) as bar:
        for run in runs:
            bar.set_postfix_str(f"compile + warm-up {run.label}", refresh=False)
            exe, run.compile_s = _compiled(cache, run)
            start = time.perf_counter()
            run.output = jax.device_get(jax.block_until_ready(exe(*run.args)))
            run.first_s = time.perf_counter() - start
            bar.update()
        for k in range(repeats):
            bar.set_postfix_str(f"timing round {k + 1}/{repeats}", refresh=False)
            for run in runs:
                exe = cache[run.key][0]
                start = time.perf_counter()
                jax.block_until_ready(exe(*run.args))
                run.samples.append(time.perf_counter() - start)
                bar.update()
    return runs


