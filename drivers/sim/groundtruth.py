"""Ground-truth views of a simulated recording, for the emulated DA3 (models/) and for checks.

`GroundTruthSource.render_view(t_ns, K, width, height)` casts the scene through an UNDISTORTED
pinhole camera with intrinsics K placed at the true camera pose of the frame stamped t_ns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.sim.render import Caster, pinhole_ray_grid
from drivers.sim.scene import Scene
from drivers.sim.texture import REFLECTIVE
from runtime.errors import ConfigError


@dataclass
class GroundTruthView:
    """What an ideal pinhole camera sees at a frame's true pose.

    Attributes:
        depth: (H,W) float32 z-depth in the camera frame, m (np.inf where no surface is hit).
        T_WC: (4,4) true camera pose in the world (x_W = T_WC x_C).
        texture: (H,W) float32 local texture strength of the surface seen, in [0, 1] (0 = textureless).
        reflective: (H,W) bool, True where the surface is reflective-like (view-dependent appearance).
        dynamic: (H,W) bool, True on moving objects (always False: simulated scenes are static).
        surface_id: (H,W) int32 id of the box face seen (-1 = none); changes mark depth discontinuities
            or creases.
    """

    depth: np.ndarray
    T_WC: np.ndarray
    texture: np.ndarray
    reflective: np.ndarray
    dynamic: np.ndarray
    surface_id: np.ndarray


class GroundTruthSource:
    """Renders ground-truth views of a scene along a motion.

    Args:
        scene: the simulated scene.
        motion: an object with pose(t_ns) -> (R_WI (N,3,3), p_WI (N,3)) (PoseSpline, SampledMotion).
        T_IC: (4,4) camera pose in the IMU/body frame.
        time_offset_ns: camera-to-IMU clock offset, t_imu = t_cam + time_offset_ns.
    """

    def __init__(self, scene: Scene, motion, T_IC: np.ndarray, time_offset_ns: int = 0) -> None:
        self.scene = scene
        self.motion = motion
        self.T_IC = np.asarray(T_IC, dtype=np.float64)
        self.time_offset_ns = int(time_offset_ns)
        self._casters: dict[tuple, Caster] = {}

    def camera_pose(self, t_ns: int) -> np.ndarray:
        """(4,4) true T_WC of the frame stamped t_ns (camera clock)."""
        R, p = self.motion.pose(np.array([int(t_ns) + self.time_offset_ns]))
        T_WI = np.eye(4)
        T_WI[:3, :3], T_WI[:3, 3] = R[0], p[0]
        return T_WI @ self.T_IC

    def render_view(self, t_ns: int, K: np.ndarray, width: int, height: int) -> GroundTruthView:
        """The ground-truth view of the frame stamped t_ns (camera clock, int64 ns) through a pinhole
        camera with intrinsics K (3x3, pixels) and size width x height."""
        if int(width) < 1 or int(height) < 1:
            raise ConfigError(f"view size must be positive, got {width}x{height}")
        K = np.asarray(K, dtype=np.float64)
        key = (K.tobytes(), int(width), int(height))
        caster = self._casters.get(key)
        if caster is None:
            if len(self._casters) > 8:
                self._casters.clear()
            caster = Caster(self.scene, pinhole_ray_grid(K, int(width), int(height)), 1.0 / float(K[0, 0]))
            self._casters[key] = caster
        T_WC = self.camera_pose(t_ns)
        view = caster.cast(T_WC[:3, :3], T_WC[:3, 3], want_strength=True)
        mats = self.scene.face_material
        reflective = np.zeros(view.face.shape, bool)
        hit = view.face >= 0
        reflective[hit] = mats[view.face[hit]] == REFLECTIVE
        return GroundTruthView(
            depth=view.depth,
            T_WC=T_WC,
            texture=view.strength,
            reflective=reflective,
            dynamic=np.zeros(view.face.shape, bool),
            surface_id=view.face,
        )
