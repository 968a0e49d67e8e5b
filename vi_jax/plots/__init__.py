"""Figures: vehicle runs (seed 000 Figures 1–3), the beam (seed 003 Figs. 6–7), the Clebsch
rigid body (seed 002 Figure 1), the work-precision study and fits. Each module imports
matplotlib itself; nothing here is imported by the engine."""

from .beam import plot_beam_shapes as plot_beam_shapes, plot_conservation as plot_conservation
from .vehicle import (
    plot_energy_error as plot_energy_error,
    plot_kelvin_noether_error as plot_kelvin_noether_error,
    plot_trajectory as plot_trajectory,
    plot_vehicle_run as plot_vehicle_run,
)
