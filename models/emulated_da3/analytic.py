"""A closed-form ground-truth source: a box room with a box, a mirror, a bare wall and no ceiling.

Used to test and demonstrate the emulated DA3 without the simulator. World: z up, metres. The
camera (OpenCV axes: x right, y down, z forward) slides sideways along y while looking at a fixed
target, so every pose is known in closed form; ray casting is exact (slab tests).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NS = 1_000_000_000


@dataclass(frozen=True)
class BoxRoomView:
    """A rendered view (satisfies `GroundTruthView`)."""

    depth: np.ndarray
    T_WC: np.ndarray
    texture: np.ndarray
    reflective: np.ndarray
    dynamic: np.ndarray
    surface_id: np.ndarray


def look_at(centre: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(4,4) T_WC of a camera at `centre` looking at `target`, image x horizontal (world z up)."""
    f = target - centre
    f = f / np.linalg.norm(f)
    x = np.cross(f, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(f, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, f], axis=1)
    T[:3, 3] = centre
    return T


class BoxRoom:
    """Room [room_min, room_max] without ceiling, one solid box inside, a mirror on the +x wall.

    Surface ids: room walls 0..4 (x-, x+, y-, y+, floor), box faces 6..11 (x-, x+, y-, y+, z-, z+),
    mirror 12. Texture strength: the +y wall 0.005 (bare paint), the floor 0.5, everything else 0.8.

    Args:
        start: camera centre at t = 0 (m).
        velocity: camera velocity (m/s), constant.
        target: the point the camera looks at (m).
        dynamic_box: mark the box's pixels as moving (its geometry stays put).
    """

    room_min = np.array([-4.0, -3.0, 0.0])
    room_max = np.array([4.0, 3.0, 2.2])
    box_min = np.array([0.4, -0.7, 0.0])
    box_max = np.array([1.4, 0.5, 1.1])
    mirror_y = (-2.5, -1.0)
    mirror_z = (0.3, 1.9)

    def __init__(
        self,
        start=(-2.5, -0.8, 1.3),
        velocity=(0.0, 0.5, 0.05),
        target=(1.0, 0.0, 0.6),
        dynamic_box: bool = False,
    ) -> None:
        self.start = np.asarray(start, np.float64)
        self.velocity = np.asarray(velocity, np.float64)
        self.target = np.asarray(target, np.float64)
        self.dynamic_box = dynamic_box

    def T_WC(self, t_ns: int) -> np.ndarray:
        """(4,4) true camera-to-world pose at t_ns."""
        return look_at(self.start + self.velocity * (t_ns / NS), self.target)

    def render_view(self, t_ns: int, K: np.ndarray, width: int, height: int) -> BoxRoomView:
        """Exact z-depth and attributes of the view at t_ns through pinhole K."""
        T = self.T_WC(t_ns)
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        rays_c = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T  # z = 1: ray parameter = z-depth
        d = rays_c @ T[:3, :3].T
        o = T[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            # leaving the room (camera inside): smallest positive exit over the axes
            t_hi = np.where(
                d > 0, (self.room_max - o) * inv, np.where(d < 0, (self.room_min - o) * inv, np.inf)
            )
            axis = np.argmin(t_hi, axis=-1)
            t_room = np.take_along_axis(t_hi, axis[..., None], -1)[..., 0]
            sign = np.take_along_axis(d, axis[..., None], -1)[..., 0] > 0
            room_id = 2 * axis + sign  # x-, x+, y-, y+, z-, z+ -> 0..5
            # entering the box (camera outside): slab test
            t1, t2 = (self.box_min - o) * inv, (self.box_max - o) * inv
            t_lo = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))
            t_up = np.where(np.isnan(t1), np.inf, np.maximum(t1, t2))
        b_axis = np.argmax(t_lo, axis=-1)
        t_near = np.take_along_axis(t_lo, b_axis[..., None], -1)[..., 0]
        t_far = np.min(t_up, axis=-1)
        hit_box = (t_near <= t_far) & (t_near > 0) & (t_near < t_room)
        b_sign = np.take_along_axis(d, b_axis[..., None], -1)[..., 0] < 0  # entering through the max face
        box_id = 6 + 2 * b_axis + b_sign
        depth = np.where(hit_box, t_near, t_room)
        sid = np.where(hit_box, box_id, room_id).astype(np.int32)
        sky = (~hit_box) & (room_id == 5)
        depth = np.where(sky, np.inf, depth)
        sid = np.where(sky, -1, sid).astype(np.int32)
        p = o + d * np.where(np.isfinite(depth), depth, 0.0)[..., None]
        mirror = (
            (sid == 1)
            & (p[..., 1] > self.mirror_y[0])
            & (p[..., 1] < self.mirror_y[1])
            & (p[..., 2] > self.mirror_z[0])
            & (p[..., 2] < self.mirror_z[1])
        )
        sid = np.where(mirror, 12, sid).astype(np.int32)
        texture = np.full((height, width), 0.8, np.float32)
        texture[sid == 3] = 0.005
        texture[sid == 4] = 0.5
        texture[sid == -1] = 0.0
        dynamic = (sid >= 6) & (sid <= 11) if self.dynamic_box else np.zeros((height, width), bool)
        return BoxRoomView(depth.astype(np.float32), T, texture, mirror, dynamic, sid)
