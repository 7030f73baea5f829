"""Triangle-mesh primitives for the simulated world.

Every function returns ``(vertices_m, triangles)``: (V, 3) float64 world-frame vertices in metres and
(T, 3) int64 vertex indices. Triangle winding is not relied upon anywhere (the sensor uses the
absolute cosine of the incidence angle), but faces are wound counter-clockwise seen from outside.
Shapes are closed where that is cheap, so a ray never slips between two faces of one object.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "Mesh",
    "box",
    "cylinder",
    "ellipsoid",
    "gable_roof",
    "heightfield",
    "merge",
    "rotation_to_normal",
    "rotation_z",
    "scattered_leaves",
]

Mesh = tuple[np.ndarray, np.ndarray]

# A unit cube [-0.5, 0.5]^3: vertex i has bits (x, y, z) = (i & 1, i >> 1 & 1, i >> 2 & 1).
_CUBE_VERTICES = np.array([[(i & 1) - 0.5, ((i >> 1) & 1) - 0.5, ((i >> 2) & 1) - 0.5] for i in range(8)])
_CUBE_TRIANGLES = np.array(
    [
        [0, 2, 1],
        [1, 2, 3],  # bottom (z-)
        [4, 5, 6],
        [5, 7, 6],  # top (z+)
        [0, 1, 4],
        [1, 5, 4],  # y-
        [2, 6, 3],
        [3, 6, 7],  # y+
        [0, 4, 2],
        [2, 4, 6],  # x-
        [1, 3, 5],
        [3, 7, 5],  # x+
    ],
    dtype=np.int64,
)


def rotation_z(yaw_rad: float) -> np.ndarray:
    """3x3 rotation about the world z axis by ``yaw_rad`` (counter-clockwise seen from above)."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_to_normal(normal: np.ndarray, yaw_rad: float) -> np.ndarray:
    """Rotation whose z column is the unit ``normal`` and whose x column points along ``yaw_rad``.

    Used to tilt small objects (parked cars) onto sloped terrain.
    """
    up = np.asarray(normal, float) / np.linalg.norm(normal)
    heading = np.array([np.cos(yaw_rad), np.sin(yaw_rad), 0.0])
    forward = heading - up * (heading @ up)
    forward /= np.linalg.norm(forward)
    left = np.cross(up, forward)
    return np.column_stack([forward, left, up])


def box(size_m, center_m, rotation: np.ndarray | None = None) -> Mesh:
    """A cuboid of edge lengths ``size_m`` (3,) centred at ``center_m`` (3,), rotated by ``rotation``."""
    vertices = _CUBE_VERTICES * np.asarray(size_m, float)
    if rotation is not None:
        vertices = vertices @ np.asarray(rotation, float).T
    return vertices + np.asarray(center_m, float), _CUBE_TRIANGLES.copy()


def gable_roof(length_m: float, width_m: float, rise_m: float, base_center_m, yaw_rad: float) -> Mesh:
    """A triangular prism roof: ridge along the local x axis, eaves ``width_m`` apart at the base."""
    hl, hw = 0.5 * length_m, 0.5 * width_m
    local = np.array(
        [
            [-hl, -hw, 0.0],
            [hl, -hw, 0.0],
            [hl, hw, 0.0],
            [-hl, hw, 0.0],  # eaves rectangle
            [-hl, 0.0, rise_m],
            [hl, 0.0, rise_m],  # ridge
        ]
    )
    triangles = np.array(
        [
            [0, 1, 5],
            [0, 5, 4],  # slope y-
            [2, 3, 4],
            [2, 4, 5],  # slope y+
            [0, 4, 3],  # gable x-
            [1, 2, 5],  # gable x+
            [0, 3, 2],
            [0, 2, 1],  # base
        ],
        dtype=np.int64,
    )
    return local @ rotation_z(yaw_rad).T + np.asarray(base_center_m, float), triangles


def cylinder(radius_m: float, z_bottom_m: float, z_top_m: float, center_xy_m, n_sides: int = 12) -> Mesh:
    """A vertical closed cylinder (prism with ``n_sides`` faces)."""
    angles = np.arange(n_sides) * (2.0 * np.pi / n_sides)
    ring = np.column_stack([np.cos(angles), np.sin(angles)]) * radius_m + np.asarray(center_xy_m, float)[:2]
    bottom = np.column_stack([ring, np.full(n_sides, z_bottom_m)])
    top = np.column_stack([ring, np.full(n_sides, z_top_m)])
    centers = np.array([[*center_xy_m[:2], z_bottom_m], [*center_xy_m[:2], z_top_m]], dtype=float)
    vertices = np.vstack([bottom, top, centers])
    i = np.arange(n_sides)
    j = (i + 1) % n_sides
    sides = np.concatenate([np.column_stack([i, j, j + n_sides]), np.column_stack([i, j + n_sides, i + n_sides])])
    bottom_cap = np.column_stack([np.full(n_sides, 2 * n_sides), j, i])
    top_cap = np.column_stack([np.full(n_sides, 2 * n_sides + 1), i + n_sides, j + n_sides])
    return vertices, np.concatenate([sides, bottom_cap, top_cap]).astype(np.int64)


def ellipsoid(radii_m, center_m, n_lat: int = 6, n_lon: int = 10) -> Mesh:
    """A closed UV ellipsoid with semi-axes ``radii_m`` (3,) centred at ``center_m``."""
    polar = np.linspace(0.0, np.pi, n_lat + 1)[1:-1]
    azimuth = np.arange(n_lon) * (2.0 * np.pi / n_lon)
    p, a = np.meshgrid(polar, azimuth, indexing="ij")
    unit = np.column_stack([(np.sin(p) * np.cos(a)).ravel(), (np.sin(p) * np.sin(a)).ravel(), np.cos(p).ravel()])
    unit = np.vstack([unit, [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]])
    vertices = unit * np.asarray(radii_m, float) + np.asarray(center_m, float)
    north, south = len(unit) - 2, len(unit) - 1
    triangles = []
    col = np.arange(n_lon)
    nxt = (col + 1) % n_lon
    for r in range(n_lat - 2):
        upper, lower = r * n_lon, (r + 1) * n_lon
        triangles.append(np.column_stack([upper + col, lower + col, lower + nxt]))
        triangles.append(np.column_stack([upper + col, lower + nxt, upper + nxt]))
    triangles.append(np.column_stack([np.full(n_lon, north), col, nxt]))
    last = (n_lat - 2) * n_lon
    triangles.append(np.column_stack([np.full(n_lon, south), last + nxt, last + col]))
    return vertices, np.concatenate(triangles).astype(np.int64)


def scattered_leaves(radii_m, center_m, n_leaves: int, size_m: tuple[float, float], rng: np.random.Generator) -> Mesh:
    """``n_leaves`` separate small triangles (leaves) at uniform random places in an ellipsoid crown.

    Each leaf is an equilateral triangle of edge length uniform in ``size_m``, in a random
    orientation. Rays find the gaps between them: a crown made this way is porous, not solid.
    """
    direction = rng.normal(size=(n_leaves, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    radius = rng.random(n_leaves) ** (1.0 / 3.0)  # uniform in the volume
    centers = direction * radius[:, None] * np.asarray(radii_m, float) + np.asarray(center_m, float)
    normal = rng.normal(size=(n_leaves, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(normal, u)
    circumradius = rng.uniform(*size_m, n_leaves) / np.sqrt(3.0)
    spin = rng.uniform(0.0, 2.0 * np.pi, n_leaves)
    angles = spin[:, None] + np.array([0.0, 2.0, 4.0]) * (np.pi / 3.0)  # (n, 3) corner angles
    corners = centers[:, None, :] + circumradius[:, None, None] * (
        np.cos(angles)[..., None] * u[:, None, :] + np.sin(angles)[..., None] * v[:, None, :]
    )
    return corners.reshape(-1, 3), np.arange(3 * n_leaves, dtype=np.int64).reshape(n_leaves, 3)


def heightfield(x_m: np.ndarray, y_m: np.ndarray, z_m: np.ndarray) -> Mesh:
    """A grid mesh over the axes ``x_m`` (nx,) and ``y_m`` (ny,) with heights ``z_m`` (ny, nx)."""
    gx, gy = np.meshgrid(x_m, y_m)
    vertices = np.column_stack([gx.ravel(), gy.ravel(), np.asarray(z_m, float).ravel()])
    nx = len(x_m)
    index = np.arange(len(y_m) * nx).reshape(len(y_m), nx)
    a = index[:-1, :-1].ravel()
    b = index[:-1, 1:].ravel()
    c = index[1:, :-1].ravel()
    d = index[1:, 1:].ravel()
    triangles = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    return vertices, triangles.astype(np.int64)


def merge(meshes: list[Mesh]) -> Mesh:
    """Concatenate meshes into one, re-indexing the triangles."""
    if not meshes:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes[:-1]])
    vertices = np.vstack([v for v, _ in meshes])
    triangles = np.vstack([t + o for (_, t), o in zip(meshes, offsets)])
    return vertices, triangles
