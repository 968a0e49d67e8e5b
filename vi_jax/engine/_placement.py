"""Where a single trajectory runs.

A single trajectory is a long chain of tiny dependent steps: on a GPU every loop iteration costs
kernel launches, so it runs about 100× slower than on the host CPU (H100 against the same
machine's CPU with the loop option: README, "Where to run"). Ensembles are the opposite: their
members fill the GPU. ``simulate(device=...)`` chooses; by default a single trajectory on an
accelerator warns once and runs where asked.
"""

import contextlib
import warnings

import jax


class PerformanceWarning(UserWarning):
    """The computation runs where it is known to be much slower than an alternative."""


_warned = False


def _accelerator_default() -> bool:
    return jax.default_backend() != "cpu"


def placement(device):
    """Context for a concrete single-trajectory run: ``device`` None (the default device; a
    one-time :class:`PerformanceWarning` on an accelerator), "cpu", or a ``jax.Device``."""
    global _warned
    if device is None:
        if _accelerator_default() and not _warned:
            _warned = True
            warnings.warn(
                "simulate: a single trajectory on an accelerator is latency-bound (about 100x slower "
                "than the host CPU); pass device='cpu' to run it there, or use vj.ensemble for many "
                "trajectories. This warning is shown once.",
                PerformanceWarning,
                stacklevel=3,
            )
        return contextlib.nullcontext()
    if isinstance(device, str):
        if device != "cpu":
            raise ValueError(f"device: expected None, 'cpu' or a jax.Device, got {device!r}")
        device = jax.devices("cpu")[0]
    if not isinstance(device, jax.Device):
        raise ValueError(f"device: expected None, 'cpu' or a jax.Device, got {device!r}")
    return jax.default_device(device)
