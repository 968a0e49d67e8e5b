"""Where a single trajectory runs.

A single trajectory is a long chain of tiny dependent steps: on a GPU every loop iteration costs
kernel launches, so it runs 15–100× slower than on the host CPU (an H100: 158–162 µs per vehicle
step, against 8.1–10.2 µs on the same machine's CPU with default XLA flags and 1.5–1.8 µs with the
loop option; an H200: 75.7 µs against 4.50 and 1.01 µs: README, "Where to run"). Ensembles are the opposite: their
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
                "simulate: a single trajectory on an accelerator is latency-bound (15-100x slower "
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


def target_platform(mesh=None) -> str:
    """The platform ("cpu", "gpu", "tpu") a computation will run on: the ``mesh``'s devices,
    else the default device (``jax.default_device``), else the default backend."""
    if mesh is not None:
        return mesh.devices.flat[0].platform
    device = jax.config.jax_default_device
    if isinstance(device, jax.Device):
        return device.platform
    if isinstance(device, str):
        return jax.devices(device)[0].platform
    return jax.default_backend()
