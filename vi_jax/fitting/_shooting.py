"""Multiple shooting for the vehicle fit: the record cut into segments of equal numbers of steps,
each integrated by ``vj.simulate`` from its own unknown initial state, the residuals of the
telemetry at its sample times, and (with more than one segment) continuity residuals between each
segment's end and the next one's start. One segment is single shooting.

Unknowns z = (θ_free, s_0, …, s_{S−1}); a segment state s = (δ, ω, q, ν) gives R = R̄·exp(δ̂)
(R̄ a fixed reference), body angular velocity ω, position q and body velocity ν (q̇ = Rν).

Samples between grid nodes are interpolated consistently with the discrete trajectory: position
by the cubic Hermite interpolant of the nodes' q and q̇ = Rν; attitude by R_a·exp(ψ̂(σ)) with ψ the
cubic Hermite interpolant of 0, hω_a, log(R_aᵀR_b), h(ω_b + ½ψ(1)×ω_b) (the tangent of the
rotation-vector chart to first order); rates and body velocities linearly. The interpolation is
exact at the nodes and O(h³) between them, below the O(h) and O(h²) error of orders 1 and 2.

The Jacobian: forward mode through each segment's steps with respect to (θ_free, s_j) only (a
segment depends on no other segment's state), segment after segment (:func:`segment_sweeps`),
then pushed through the interpolation and the residual maps (cheap, linearised once) column by
column.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._system import State
from ..engine import simulate
from ..engine._compile_options import single_trajectory_jit
from ..engine._placement import target_platform
from ..lie._so3 import so3_exp, so3_log, unskew3
from ._robust import robust_residuals
from ._telemetry import CHANNELS

STATE_SIZE = 12


CONTINUITY_SCALE = {"attitude": 0.01, "rates": 0.01, "position": 0.01, "velocity": 0.01}


class Layout(eqx.Module):
    """``segments`` segments of ``steps`` steps of size ``h`` from ``t0``, and the position of each
    sample: segment, node within it and fraction of the step."""

    t0: float = eqx.field(static=True)
    h: float = eqx.field(static=True)
    segments: int = eqx.field(static=True)
    steps: int = eqx.field(static=True)
    segment: jax.Array
    node: jax.Array
    fraction: jax.Array

    def __init__(self, t, t0, h, segments, total_steps):
        self.t0, self.h, self.segments = float(t0), float(h), int(segments)
        self.steps = -(-int(total_steps) // self.segments)
        u = (np.asarray(t) - self.t0) / self.h
        k = np.clip(np.floor(u + 1e-9).astype(int), 0, self.segments * self.steps - 1)
        self.segment = jnp.asarray(k // self.steps)
        self.node = jnp.asarray(k % self.steps)
        self.fraction = jnp.asarray(u - k)

    def start_times(self):
        return self.t0 + self.h * self.steps * np.arange(self.segments)


def start_state(s, R_ref):
    R = R_ref @ so3_exp(s[:3])
    return State(g=R, xi=s[3:6], q=s[6:9], qdot=R @ s[9:12])


def _segment_nodes(z, R_ref, model_of, layout, tau, order, n_free):
    """Nodes (R, ω, q, ν) of one segment from z = (θ_free, s), and whether every step succeeded."""
    model = model_of(z[:n_free])
    sol = simulate(model, start_state(z[n_free:], R_ref), layout.h, layout.steps, tau=tau, order=order, throw=False)
    nodes = (sol.R, sol.omega, sol.q, sol.nu)
    return nodes, (nodes, sol.succeeded)


def _interpolate(nodes, layout):
    """(R, ω, q, ν) at the sample times (see the module docstring)."""
    R, omega, q, nu = nodes
    j, a, s = layout.segment, layout.node, layout.fraction
    h = layout.h
    Ra, Rb, wa, wb = R[j, a], R[j, a + 1], omega[j, a], omega[j, a + 1]
    qa, qb = q[j, a], q[j, a + 1]
    va, vb = jnp.einsum("nij,nj->ni", Ra, nu[j, a]), jnp.einsum("nij,nj->ni", Rb, nu[j, a + 1])
    s_ = s[:, None]
    h00, h10, h01, h11 = 2 * s_**3 - 3 * s_**2 + 1, s_**3 - 2 * s_**2 + s_, -2 * s_**3 + 3 * s_**2, s_**3 - s_**2
    position = h00 * qa + h10 * h * va + h01 * qb + h11 * h * vb
    phi = jax.vmap(lambda A, B: so3_log(A.T @ B))(Ra, Rb)
    psi = h10 * h * wa + h01 * phi + h11 * h * (wb + 0.5 * jnp.cross(phi, wb))
    attitude = jnp.einsum("nij,njk->nik", Ra, jax.vmap(so3_exp)(psi))
    rates = (1 - s_) * wa + s_ * wb
    velocity = (1 - s_) * nu[j, a] + s_ * nu[j, a + 1]
    return {"attitude": attitude, "rates": rates, "position": position, "velocity": velocity}


def samples_of(telemetry):
    """The arrays of ``telemetry`` that the residuals use: (values, mask, scale) over every
    channel (the given channels and noise levels are not compiled in)."""
    return telemetry.values, telemetry.mask, telemetry.scale


def observation_residuals(nodes, layout, samples, loss):
    """Whitened, masked and robustified residuals of every channel (rows: channel by channel in
    the order of ``CHANNELS``, then sample, then component) and the model at the sample times."""
    values, mask, scale = samples
    model = _interpolate(nodes, layout)
    out = []
    for c in CHANNELS:
        if c == "attitude":
            diff = unskew3(jnp.einsum("nji,njk->nik", values[c], model[c]))
        else:
            diff = model[c] - values[c]
        out.append((robust_residuals(diff / scale[c], loss) * mask[c]).ravel())
    return jnp.concatenate(out), model


def continuity_residuals(nodes, states, R_ref, weight):
    """Each segment's end against the next one's start, in units of ``CONTINUITY_SCALE``, times
    ``weight``."""
    R, omega, q, nu = (x[:-1, -1] for x in nodes)
    start = jax.vmap(start_state)(states[1:], R_ref[1:])
    parts = [
        unskew3(jnp.einsum("nji,njk->nik", start.g, R)) / CONTINUITY_SCALE["attitude"],
        (omega - start.xi) / CONTINUITY_SCALE["rates"],
        (q - start.q) / CONTINUITY_SCALE["position"],
        (nu - states[1:, 9:12]) / CONTINUITY_SCALE["velocity"],
    ]
    return weight * jnp.concatenate(parts, axis=1).ravel()


def segment_sweeps(theta_free, states, R_ref, model_of, layout, tau, order):
    """Each segment's nodes, their forward-mode derivatives with respect to (θ_free, s_j) and
    whether its steps succeeded: one segment after another (``lax.map``) where the program runs
    on a CPU, all of them in one ``vmap`` on an accelerator. On the CPU the fit's two programs
    (64 segments; single shooting) reach their first result in 0.66–0.96× the time of the
    ``vmap``'s (trace and compile; medians 0.72–0.81× per program) and run in 0.78–1.13× (medians;
    ``python benchmarks/fit_segments.py``, three alternate rounds of fresh processes, orders 1 and
    2): the step is traced and compiled for one trajectory, not batched over the segments."""
    n_free = theta_free.size

    def one_segment(s_and_R):
        z = jnp.concatenate([theta_free, s_and_R[0]])
        return jax.jacfwd(_segment_nodes, has_aux=True)(z, s_and_R[1], model_of, layout, tau, order, n_free)

    if target_platform() == "cpu":
        return jax.lax.map(one_segment, (states, R_ref))
    return jax.vmap(one_segment)((states, R_ref))


@functools.partial(single_trajectory_jit, forward_only=False)
def residuals_and_jacobian(theta_free, states, R_ref, model_of, layout, samples, weight, loss, tau, order):
    """Residuals r (observations, then continuity), their Jacobian with respect to
    (θ_free, states.ravel()), whether every step of every segment succeeded, and the model at
    the sample times. A program of single trajectories (each segment's forward-mode sweep),
    compiled with XLA:CPU's elemental emitters as ``vj.simulate``'s concrete calls are, keeping
    Newton's implicit-function rule for its Jacobian: the two programs of ``python
    benchmarks/fit_time.py``'s fit compile in 0.66–0.84× the time and run in 0.99–1.11× (``python
    benchmarks/emitters.py [--fast-loops]``, rows "fit Jacobian"); the first fit took 0.82–0.89×
    (default XLA) and 0.79–0.86× (loop option) the time of the fusion emitters' in alternate
    processes."""
    n_free, n_seg = theta_free.size, layout.segments
    dnodes, (nodes, ok) = segment_sweeps(theta_free, states, R_ref, model_of, layout, tau, order)

    def F(nodes, states):
        obs, model = observation_residuals(nodes, layout, samples, loss)
        if n_seg > 1:
            obs = jnp.concatenate([obs, continuity_residuals(nodes, states, R_ref, weight)])
        return obs, model

    r, F_lin, model = jax.linearize(F, nodes, states, has_aux=True)
    n_cols = n_free + STATE_SIZE * n_seg
    cols = jnp.arange(n_cols)
    # Column c: which entry of a segment's (θ_free, s) it moves, and in which segment (−1: all).
    entry = jnp.where(cols < n_free, cols, n_free + (cols - n_free) % STATE_SIZE)
    seg = jnp.where(cols < n_free, -1, (cols - n_free) // STATE_SIZE)

    def column(e, g):
        in_seg = (g < 0) | (jnp.arange(n_seg) == g)
        d_nodes = jax.tree.map(lambda J: jnp.where(in_seg.reshape((-1,) + (1,) * (J.ndim - 2)), J[..., e], 0.0), dnodes)
        d_states = jnp.zeros_like(states).at[jnp.maximum(g, 0), jnp.maximum(e - n_free, 0)].set(jnp.where(g >= 0, 1.0, 0.0))
        return F_lin(d_nodes, d_states)

    J = jax.lax.map(lambda eg: column(*eg), (entry, seg), batch_size=16).T
    return r, J, jnp.all(ok), model
