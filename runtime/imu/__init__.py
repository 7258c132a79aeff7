"""IMU preintegration on the manifold with bias Jacobians, and navigation-state propagation."""
from __future__ import annotations

from runtime.imu.preintegration import Preintegration, Preintegrator
from runtime.imu.propagation import integrate_state
from runtime.imu.samples import as_imu_arrays, check_imu_arrays, imu_nodes, imu_segment

__all__ = ["Preintegration", "Preintegrator", "as_imu_arrays", "check_imu_arrays", "imu_nodes", "imu_segment",
           "integrate_state"]
