"""Scenes of the stability study, built from arrays so that one compiled program serves every
sweep: ``build(kind, params) -> (system, x0)`` with ``params`` a dict of arrays (inertia, spin
vector ω₀, …), and ``run_vi`` / ``run_diffrax`` returning per-run diagnostics (vmappable over
``params`` and ``h``)."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

import vi_jax as vj
from vi_jax import continuous

SYSTEMS = ("rigid_body", "heavy_top", "underwater_vehicle")
VI_SCHEMES = tuple(f"{tau}{order}" for tau in ("cayley", "exp") for order in (1, 2, 4, 6))
SPLITTING_SCHEMES = tuple(f"splitting{order}" for order in (2, 4, 6, 8))  # explicit: no Newton
DIFFRAX_SCHEMES = ("Tsit5", "Dopri8", "Kvaerno5")

# Failure codes: 0-3 as in vj.Solution.result; 4: a diffrax solve that stopped (any reason).
DIFFRAX_FAILED = 4
TINY = 1e-300


def default_params(kind):
    """Default parameters of each scene as numpy arrays; ``omega`` is the unit spin direction."""
    if kind == "rigid_body":
        model = vj.models.RigidBody()
        x0 = model.initial_state()
        params = dict(inertia=np.diag(model.inertia))
    elif kind == "heavy_top":
        model = vj.models.HeavyTop()
        x0 = model.initial_state()
        params = dict(inertia=np.diag(model.inertia), R0=np.asarray(x0.g))
    elif kind == "underwater_vehicle":
        model = vj.models.UnderwaterVehicle()
        x0 = model.initial_state()
        params = dict(
            inertia=np.diag(model.inertia), added_mass=np.diag(model.added_mass),
            R0=np.asarray(x0.g), q0=np.asarray(x0.q), v0=np.asarray(x0.qdot),
        )
    else:
        raise ValueError(f"kind: expected one of {SYSTEMS}, got {kind!r}")
    xi = np.asarray(x0.xi)
    params["omega"] = xi / np.linalg.norm(xi)
    return {k: np.asarray(v, float) for k, v in params.items()}


def build(kind, p):
    """(system, x0) from a params dict (arrays; traced under vmap)."""
    if kind == "rigid_body":
        system = vj.models.RigidBody(inertia=p["inertia"])
        return system, vj.State(g=jnp.eye(3, dtype=p["omega"].dtype), xi=p["omega"])
    if kind == "heavy_top":
        system = vj.models.HeavyTop(inertia=p["inertia"])
        return system, vj.State(g=p["R0"], xi=p["omega"])
    system = vj.models.UnderwaterVehicle(inertia=p["inertia"], added_mass=p["added_mass"])
    return system, vj.State(g=p["R0"], xi=p["omega"], q=p["q0"], qdot=p["v0"])


def _max_finite(x):
    """max of x, +inf if any entry is not finite."""
    return jnp.max(jnp.where(jnp.isfinite(x), x, jnp.inf))


def _errors(energy, kn, kn_scale0, g_residual):
    rel_e = jnp.abs(energy - energy[0]) / jnp.maximum(jnp.abs(energy[0]), TINY)
    kn = kn.reshape(kn.shape[0], -1)
    rel_kn = jnp.max(jnp.abs(kn - kn[0]), axis=-1) / jnp.maximum(kn_scale0, TINY)
    return dict(energy=_max_finite(rel_e), kelvin_noether=_max_finite(rel_kn), group=_max_finite(g_residual))


def run_vi(kind, scheme, n_steps, save_every, p, h, **kwargs):
    """Diagnostics of one ``vj.simulate`` run (throw=False): max relative energy and
    Kelvin–Noether errors, group residual, first failure code and when it happened, Newton
    iterations, final (g, ξ)."""
    system, x0 = build(kind, p)
    tau, order = scheme.rstrip("0123456789"), int(scheme[-1])
    if tau == "splitting":
        sol = vj.simulate(system, x0, h, n_steps, scheme="splitting", order=order, save_every=save_every, **kwargs)
    else:
        sol = vj.simulate(system, x0, h, n_steps, tau=tau, order=order, save_every=save_every, throw=False, **kwargs)
    out = _errors(
        sol.energy, sol.kelvin_noether, sol.kelvin_noether_scale[0], vj.group_constraint_residual(system, sol.g)
    )
    failed = sol.result != 0
    first = jnp.argmax(failed)
    out.update(
        code=jnp.where(jnp.any(failed), sol.result[first], 0).astype(jnp.int32),
        fail_fraction=jnp.where(jnp.any(failed), first / (sol.result.shape[0] - 1), 1.0),
        newton_max=jnp.max(sol.newton_iterations),
        g_final=sol.g[-1],
        xi_final=sol.xi[-1],
    )
    return out


def _diffrax_solver(name):
    if name == "Kvaerno5":
        # Full Newton: diffrax's default VeryChord reports "nonlinear solve diverged" at fixed
        # steps as small as |hω| ≈ 0.08 (it relies on a step controller to retry).
        return diffrax.Kvaerno5(root_finder=optx.Newton(rtol=1e-10, atol=1e-10), root_find_max_steps=20)
    return getattr(diffrax, name)()


def run_diffrax(kind, scheme, n_steps, save_every, p, h):
    """The same diagnostics for a fixed-step diffrax solve of the continuous equations."""
    system, x0 = build(kind, p)
    n_saved = n_steps // save_every
    ts = h * save_every * jnp.arange(n_saved + 1, dtype=h.dtype)
    sol = diffrax.diffeqsolve(
        continuous.vector_field(system), _diffrax_solver(scheme), 0.0, ts[-1], h,
        continuous.initial_state(system, x0), stepsize_controller=diffrax.ConstantStepSize(),
        saveat=diffrax.SaveAt(ts=ts), max_steps=n_steps + 8, throw=False,
    )
    y = sol.ys
    kn = continuous.kelvin_noether(system, y)
    kn_scale0 = continuous.kelvin_noether_scale(system, jax.tree.map(lambda x: x[0], y))
    out = _errors(continuous.energy(system, y), kn, kn_scale0, vj.group_constraint_residual(system, y[0]))
    ok = sol.result == diffrax.RESULTS.successful
    finite = jnp.all(jnp.isfinite(y[1]), axis=-1)
    out.update(
        code=jnp.where(ok, 0, DIFFRAX_FAILED).astype(jnp.int32),
        fail_fraction=jnp.where(ok, 1.0, jnp.argmin(finite) / n_saved),
        newton_max=jnp.zeros((), jnp.int32),
        g_final=y[0][-1],
        xi_final=y[1][-1],
    )
    return out


def runner(kind, scheme, n_steps, save_every):
    """A jitted, vmapped ``(params batch, h batch) -> diagnostics batch``."""
    fn = run_diffrax if scheme in DIFFRAX_SCHEMES else run_vi
    return jax.jit(jax.vmap(lambda p, h: fn(kind, scheme, n_steps, save_every, p, h)))
