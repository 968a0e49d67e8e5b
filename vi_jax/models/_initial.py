"""Initial attitudes from Euler angles (NumPy: built once from constants, with no XLA program
to compile per operation)."""

import numpy as np


def _rz(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_from_zxz(psi, theta, phi):
    """Intrinsic ZXZ Euler angles: R = R_z(ψ) R_x(θ) R_z(φ)."""
    return _rz(psi) @ _rx(theta) @ _rz(phi)


def zxz_body_rates(angles, rates):
    """Body angular velocity from ZXZ angles and their rates (seed 000 spec §4):
    ω = (ψ̇ sinθ sinφ + θ̇ cosφ, ψ̇ sinθ cosφ − θ̇ sinφ, ψ̇ cosθ + φ̇)."""
    _, theta, phi = angles
    dpsi, dtheta, dphi = rates
    return np.array(
        [
            dpsi * np.sin(theta) * np.sin(phi) + dtheta * np.cos(phi),
            dpsi * np.sin(theta) * np.cos(phi) - dtheta * np.sin(phi),
            dpsi * np.cos(theta) + dphi,
        ]
    )
