"""The simulator's default rig: calib's EuRoC MAV rig (cam0 752x480 radtan, T_IC, ADIS16448, 20 Hz)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from calib import Rig


def euroc_default_rig() -> Rig:
    """calib.euroc_rig() with a zero camera-IMU time offset when the file leaves it unset."""
    from calib import euroc_rig

    rig = euroc_rig()
    return rig if rig.time_offset_s is not None else rig.replace(time_offset_s=0.0)
