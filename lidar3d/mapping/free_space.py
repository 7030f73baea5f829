"""Dynamic-object removal by free-space evidence: points in space that other sweeps see through.

Every sweep that enters the map is voxelised (``DynamicConfig.voxel_m``). Each of its occupied voxels
is tested against the sweeps of a window around it (``window_scans`` before and after, every
``probe_every``-th one: the *probes*): the voxel's centroid is projected into the probe's range image
(ring by elevation, column by azimuth) and the return in that pixel is compared with it:

* the probe's ray passes within ``pass_tolerance_m`` of the centroid and returns at least
  ``range_margin_m`` beyond it, and beyond the *grazing slack* of the surface it hit (see
  :func:`voxel_evidence`: a ray skimming the road returns far beyond a road voxel it passes over),
  and not in front of the voxel's own surface (``surface_side``: a ray passing over a car's roof,
  on the side the roof was seen from, does not go through the roof): the probe saw **through**
  the voxel (a miss);
* the ray passes within that tolerance and returns within the margin of it: a **hit**;
* the return is nearer (the voxel was occluded), or the pixel holds no return (sky, glass, a
  dropout: absent returns prove nothing), or the ray passes farther away: no evidence.

A voxel is dynamic when at least ``min_misses`` probes saw through it and by at least ``miss_ratio``
times as many probes as hit it; its points in that sweep are removed from the map. This is ray
casting done from the voxel's side (one projection per voxel and probe, instead of a walk along every
ray), so it costs a few array operations per sweep. Thin structures survive because a ray has to pass
close to the centroid of what was hit (a pole's centroid lies on the pole); surfaces seen at grazing
angles (the road far ahead, facades along the street) because a ray running along a surface is not
taken to see through the voxels on it (the grazing slack) and because they are hit about as often as
rays skim past them, and because a ray that passes in front of a voxel's own surface (its points'
mean normal, from their sweep's range image) is not taken to have gone through it; the ground also
because voxels less than ``ground_band_m`` above the lowest point of the 3x3 one-metre cells around
them are never tested. :func:`outvoted_voxels` is the vote over the whole run that
:class:`~lidar3d.mapping.dense_map.DenseMap` adds at the end.

Records: :class:`PlacedSweep` in, :class:`FilteredSweep` out (a window of sweeps later: a sweep is
decided once the probes after it are known). Frames: world = the map frame; lidar = the sweep's
deskewed lidar frame at its stamp.
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lidar3d.config import DynamicConfig
from lidar3d.mapping.voxel import group_sums, key_groups, voxel_key_step, voxel_keys

__all__ = [
    "DynamicFilter",
    "FilteredSweep",
    "PlacedSweep",
    "ProbeStack",
    "SweepProbe",
    "mostly_dynamic_clusters",
    "outvoted_voxels",
    "point_normals",
    "sin_grazing",
    "surface_normals",
    "voxel_evidence",
]

_GROUND_CELL_M = 1.0  # cell of the local ground height (lowest point of the 3x3 cells around)
_NEIGHBOUR_SHIFTS = tuple((di << 32) + dj for di in (-1, 0, 1) for dj in (-1, 0, 1))


@dataclass(frozen=True, slots=True)
class PlacedSweep:
    """One deskewed sweep with its final pose.

    Attributes:
        points_lidar: (N,3) float64 metres, lidar frame at the stamp (deskewed, within range).
        points_world: (N,3) the same points in the world (map) frame.
        ring: (N,) laser index (0 = lowest beam).
        intensity: (N,) float32.
        T_world_lidar: (4,4) pose of that lidar frame in the world frame.
    """

    points_lidar: np.ndarray
    points_world: np.ndarray
    ring: np.ndarray
    intensity: np.ndarray
    T_world_lidar: np.ndarray


@dataclass(frozen=True, slots=True)
class FilteredSweep:
    """A sweep decided: its voxels (``DynamicConfig.voxel_m``) as a voxel map takes them, which of
    them lie in space seen through, and, from a filter that keeps them (``per_point``), its points.

    Attributes:
        voxel_keys: (V,) sorted keys (:func:`~lidar3d.mapping.voxel.voxel_keys`) of the sweep's voxels.
        voxel_sums: (V,5) per voxel the sums of x, y, z (world frame, metres) and intensity of its
            points, and their count.
        voxel_dynamic: (V,) bool, the voxel is dynamic (other sweeps saw through it).
        points_world: (N,3) float64 metres, world frame; None from a filter without ``per_point``.
        intensity: (N,) float32, or None as ``points_world``.
        dynamic: (N,) bool, the point lies in a dynamic voxel, or None as ``points_world``.
    """

    voxel_keys: np.ndarray
    voxel_sums: np.ndarray
    voxel_dynamic: np.ndarray
    points_world: np.ndarray | None = None
    intensity: np.ndarray | None = None
    dynamic: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class SweepProbe:
    """The range image of one sweep, as free-space evidence for the voxels of others.

    Attributes:
        origin_m: (3,) sensor position, world frame.
        R_world_lidar: (3,3) sensor orientation.
        points_lidar: (rings, bins, 3) float32 nearest return per pixel, lidar frame (0 where none).
        range_m: (rings, bins) float32 its range, 0 where the pixel holds no return.
        sin_grazing: (rings, bins) float32 sine of the angle between the ray and the surface it hit
            (:func:`sin_grazing`; 1 where unknown: taken as hit head-on).
    """

    origin_m: np.ndarray
    R_world_lidar: np.ndarray
    points_lidar: np.ndarray
    range_m: np.ndarray
    sin_grazing: np.ndarray

    @classmethod
    def of(cls, sweep: PlacedSweep, n_rings: int, n_bins: int) -> SweepProbe:
        """The probe of ``sweep``: each point into pixel (ring, azimuth bin), the nearest one kept."""
        return cls.of_points(sweep.points_lidar, sweep.ring, sweep.T_world_lidar, n_rings, n_bins)

    @classmethod
    def of_points(
        cls, points_lidar: np.ndarray, ring: np.ndarray, T_world_lidar: np.ndarray, n_rings: int, n_bins: int
    ) -> SweepProbe:
        """The probe of (N,3) deskewed lidar-frame points with their (N,) rings, at pose (4,4)."""
        image = _RangeImage.of(points_lidar, ring, n_rings, n_bins)
        T = T_world_lidar
        return cls(
            T[:3, 3].copy(), T[:3, :3].copy(), image.points, image.range_m, sin_grazing(image.points, image.range_m)
        )


@dataclass(frozen=True, slots=True)
class _RangeImage:
    """Points in a (rings, bins) image, the nearest return per pixel.

    Attributes:
        points: (rings, bins, 3) float32 lidar frame, 0 where the pixel holds no return.
        range_m: (rings, bins) float32, 0 where none.
        pixel: (N,) flat pixel of each point put in.
        point_range_m: (N,) float32 each point's range.
    """

    points: np.ndarray
    range_m: np.ndarray
    pixel: np.ndarray
    point_range_m: np.ndarray

    @classmethod
    def of(
        cls, points_lidar: np.ndarray, ring: np.ndarray, n_rings: int, n_bins: int, *, nearest: bool = True
    ) -> _RangeImage:
        """The image of (N,3) points and their (N,) rings; ``nearest=False`` keeps whichever point of
        a pixel numpy writes last instead of the nearest (no sort: a third of the time; pixels
        holding two points are rare)."""
        points = np.asarray(points_lidar, dtype=np.float64)
        range_m = np.linalg.norm(points, axis=1)
        pixel = np.asarray(ring).astype(np.int64) * n_bins + _azimuth_bin(points, n_bins)
        order = np.argsort(-range_m, kind="stable") if nearest else slice(None)  # nearest written last wins
        image_points = np.zeros((n_rings * n_bins, 3), np.float32)
        image_range = np.zeros(n_rings * n_bins, np.float32)
        image_points[pixel[order]] = points[order]
        image_range[pixel[order]] = range_m[order]
        return cls(
            image_points.reshape(n_rings, n_bins, 3),
            image_range.reshape(n_rings, n_bins),
            pixel,
            range_m.astype(np.float32),
        )


def _cross_normals(points: np.ndarray, range_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel of a range image (``points`` (rings, bins, 3), ``range_m`` (rings, bins), 0 where
    none) the (rings, bins, 3) unnormalised normal of the surface it hit, and (rings, bins) whether
    it is known: the cross product of the tangents to the pixel's neighbours in azimuth (two columns
    away) and in ring, on each axis the neighbour nearer in range (the same surface, more likely)."""
    valid = range_m > 0.0
    # |point| of every pixel once: each neighbour's is the same array shifted (as the points are)
    length = np.linalg.norm(points, axis=-1)

    def tangent(
        shifted: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], ok_before: np.ndarray, ok_after: np.ndarray
    ):
        """Tangent to the neighbour nearer in range of the two ``shifted`` gives (points, lengths)."""
        (before, after), (length_before, length_after) = shifted(points), shifted(length)
        gap_before = np.where(ok_before, np.abs(length_before - range_m), np.inf)
        gap_after = np.where(ok_after, np.abs(length_after - range_m), np.inf)
        use_after = gap_after < gap_before
        return np.where(use_after[..., None], after, before) - points, np.isfinite(np.minimum(gap_before, gap_after))

    step = 2

    def along_azimuth_of(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.roll(image, step, axis=1), np.roll(image, -step, axis=1)

    def along_ring_of(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.concatenate([image[:1], image[:-1]]), np.concatenate([image[1:], image[-1:]])

    along_azimuth, ok_azimuth = tangent(along_azimuth_of, np.roll(valid, step, 1), np.roll(valid, -step, 1))
    valid_below = np.concatenate([np.zeros_like(valid[:1]), valid[:-1]])
    valid_above = np.concatenate([valid[1:], np.zeros_like(valid[:1])])
    along_ring, ok_ring = tangent(along_ring_of, valid_below, valid_above)
    return np.cross(along_azimuth, along_ring), valid & ok_azimuth & ok_ring


def sin_grazing(points: np.ndarray, range_m: np.ndarray) -> np.ndarray:
    """Per pixel of a range image, the sine of the angle between the ray and the surface it hit
    (:func:`_cross_normals`). A ray meeting a wall head-on gives 1; one skimming the road far ahead
    a few hundredths.

    Args:
        points: (rings, bins, 3) nearest return per pixel, lidar frame (0 where none).
        range_m: (rings, bins) its range, 0 where none.

    Returns:
        (rings, bins) float32 in [0, 1]; 1 where a neighbour on either axis is missing.
    """
    normal, known = _cross_normals(points, range_m)
    norm = np.linalg.norm(normal, axis=-1) * np.maximum(range_m, 1e-9)
    sine = np.abs(np.einsum("rbk,rbk->rb", normal, points)) / np.maximum(norm, 1e-12)
    known &= norm > 1e-12
    return np.where(known, np.clip(sine, 0.0, 1.0), 1.0).astype(np.float32)


def surface_normals(points: np.ndarray, range_m: np.ndarray) -> np.ndarray:
    """Per pixel of a range image, the unit normal of the surface it hit (:func:`_cross_normals`),
    turned towards the sensor (``normal . point < 0``).

    Args:
        points: (rings, bins, 3) nearest return per pixel, lidar frame (0 where none).
        range_m: (rings, bins) its range, 0 where none.

    Returns:
        (rings, bins, 3) float32 unit normals, lidar frame; 0 where unknown.
    """
    normal, known = _cross_normals(points, range_m)
    norm = np.linalg.norm(normal, axis=-1)
    known &= norm > 1e-12
    facing = -np.sign(np.einsum("rbk,rbk->rb", normal, points))
    scale = np.where(known, facing / np.maximum(norm, 1e-12), 0.0)
    return (normal * scale[..., None]).astype(np.float32)


def point_normals(points_lidar: np.ndarray, ring: np.ndarray, n_rings: int, n_bins: int) -> np.ndarray:
    """(N,3) float32 the :func:`surface_normals` of (N,3) lidar-frame points with their (N,) rings, in
    the lidar frame; 0 where unknown, also for a point another return of its pixel displaced."""
    image = _RangeImage.of(points_lidar, ring, n_rings, n_bins, nearest=False)
    normal = surface_normals(image.points, image.range_m).reshape(-1, 3)[image.pixel]
    normal[image.range_m.reshape(-1)[image.pixel] != image.point_range_m] = 0.0
    return normal


def _nearest_around(range_m: np.ndarray) -> np.ndarray:
    """(rings, bins) float32: per pixel of a (rings, bins) range image (0: no return) the nearest
    return of the pixel and its eight neighbours (columns wrap around), 0 where none holds one."""
    r = np.where(range_m > 0.0, range_m, np.inf)
    across = np.minimum(np.minimum(r, np.roll(r, 1, axis=1)), np.roll(r, -1, axis=1))
    nearest = across.copy()
    nearest[1:] = np.minimum(nearest[1:], across[:-1])
    nearest[:-1] = np.minimum(nearest[:-1], across[1:])
    return np.where(np.isfinite(nearest), nearest, 0.0).astype(np.float32)


def _azimuth_bin(points: np.ndarray, n_bins: int) -> np.ndarray:
    azimuth = np.arctan2(points[:, 1], points[:, 0])
    return (np.floor((azimuth + np.pi) * (n_bins / (2.0 * np.pi))).astype(np.int64)) % n_bins


class ProbeStack:
    """Probes held in fixed slots of stacked arrays, so that voxels are tested against many probes
    in one pass (see :func:`voxel_evidence`).

    Args:
        n_slots: probes held at most; ``n_rings``, ``n_bins``: their image size.
        neighbourhood: also keep ``nearest_around_m``, (n_slots, n_rings, n_bins) float32 metres:
            per pixel the nearest return among it and its eight neighbours (the rings above and
            below, none past the first and last ring; the columns either side, wrapping round the
            sweep; 0 where none of them holds one), which :func:`voxel_evidence` then asks of
            every ray that sees through; None without.
    """

    def __init__(self, n_slots: int, n_rings: int, n_bins: int, *, neighbourhood: bool = False) -> None:
        self.origin_m = np.zeros((n_slots, 3))
        self.R_world_lidar = np.tile(np.eye(3), (n_slots, 1, 1))
        self.points_lidar = np.zeros((n_slots, n_rings, n_bins, 3), np.float32)
        self.range_m = np.zeros((n_slots, n_rings, n_bins), np.float32)
        self.sin_grazing = np.ones((n_slots, n_rings, n_bins), np.float32)
        self.nearest_around_m = np.zeros((n_slots, n_rings, n_bins), np.float32) if neighbourhood else None

    @classmethod
    def of(cls, probes: list[SweepProbe], *, neighbourhood: bool = False) -> ProbeStack:
        """A stack holding ``probes`` in slots 0, 1, ..."""
        n_rings, n_bins = probes[0].range_m.shape if probes else (1, 1)
        stack = cls(len(probes), n_rings, n_bins, neighbourhood=neighbourhood)
        for slot, probe in enumerate(probes):
            stack.put(slot, probe)
        return stack

    def put(self, slot: int, probe: SweepProbe) -> None:
        """Hold ``probe`` in ``slot`` (replacing the one there)."""
        self.origin_m[slot] = probe.origin_m
        self.R_world_lidar[slot] = probe.R_world_lidar
        self.points_lidar[slot] = probe.points_lidar
        self.range_m[slot] = probe.range_m
        self.sin_grazing[slot] = probe.sin_grazing
        if self.nearest_around_m is not None:
            self.nearest_around_m[slot] = _nearest_around(probe.range_m)


def voxel_evidence(
    centroids_world: np.ndarray,
    stack: ProbeStack,
    slots: np.ndarray,
    elevation_rad: np.ndarray,
    config: DynamicConfig,
    normals_world: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Hits and misses of each voxel centroid over the probes in ``slots`` of ``stack`` (see the
    module docstring).

    A ray sees through a voxel when it returns beyond it by more than ``range_margin_m`` and, with
    ``grazing_slack``, by more than the slack of the surface it hit: a voxel on that surface, offset
    from the ray by up to ``pass_tolerance_m`` plus the pose's angular error (``pose_angle_deg``)
    times the range, lies up to ``offset / sin(grazing angle)`` before the return along the ray (the
    probe's :attr:`SweepProbe.sin_grazing`). So the road a ray skims, or a facade it runs along, is
    not seen through; what stood higher above that surface than the offset is.

    With ``normals_world``, the voxel's own surface counts too: a ray that passes in front of it
    (on the side its sweep saw it from) by more than ``surface_tolerance_m`` plus
    ``surface_angle_deg`` (the angular error between the two sweeps' poses) times the range did not
    go through it, however far it returns: a ray skimming over a car's roof, or along a slope,
    passes the roof's voxels within the pass tolerance, and says nothing about them.

    With a stack that keeps the neighbourhood (:class:`ProbeStack`), the rays of the pixels around
    must have gone beyond it too (the nearest return of the pixel and its eight neighbours): a point at an
    object's silhouette, which the ray beside the object passes within the tolerance, is not taken
    to be seen through by it while the next ray hit the object; the space a moving object has left
    is seen through by every ray around.

    Args:
        centroids_world: (V,3) voxel centroids, world frame.
        stack: the probes; ``slots``: (P,) which of them to use.
        elevation_rad: (rings,) ascending beam elevations of the sensor.
        normals_world: optional (V,3) mean of each voxel's unit surface normals, each turned towards
            the sensor that saw it (shorter than 1 where they disagree, 0 where unknown).

    Returns:
        (V,) int hits and (V,) int misses.
    """
    n_voxels = len(centroids_world)
    slots = np.asarray(slots, dtype=np.int64)
    if not n_voxels or not slots.size:
        return np.zeros(n_voxels, np.int64), np.zeros(n_voxels, np.int64)
    _, n_rings, n_bins = stack.range_m.shape
    # Ring of the nearest elevation: the boundaries halfway between neighbouring beams, as sines.
    sin_boundaries = np.sin(0.5 * (elevation_rad[1:] + elevation_rad[:-1]))
    margin = config.range_margin_m
    R = stack.R_world_lidar[slots]
    # (P, V, 3) every centroid in every probe's lidar frame, R^T (c - o), flat: pair = probe * V + voxel
    local = np.matmul(centroids_world[None] - stack.origin_m[slots, None], R).reshape(-1, 3)
    x, y, z = local[:, 0], local[:, 1], local[:, 2]
    rho = np.sqrt(x * x + y * y + z * z)
    # Each test below keeps the pairs that can still give evidence, so the next works on fewer
    # (the same values as on all pairs: twice as fast on 2,000-3,000 voxels x 16-25 probes).
    pair: np.ndarray = np.flatnonzero((rho > margin) & (rho <= config.max_range_m))
    x, y, z, rho = x[pair], y[pair], z[pair], rho[pair]
    ring = np.searchsorted(sin_boundaries, z / np.maximum(rho, 1e-9))
    column = (np.floor((np.arctan2(y, x) + np.pi) * (n_bins / (2.0 * np.pi))).astype(np.int64)) % n_bins
    pixel = (slots[pair // n_voxels] * n_rings + ring) * n_bins + column
    return_m = stack.range_m.reshape(-1)[pixel].astype(np.float64)
    keep = np.flatnonzero(return_m > 0.0)  # a pixel without a return proves nothing
    pair, x, y, z, rho, pixel, return_m = (a[keep] for a in (pair, x, y, z, rho, pixel, return_m))
    flat = stack.points_lidar.reshape(-1)
    ray: tuple[np.ndarray, ...] = (flat[3 * pixel], flat[3 * pixel + 1], flat[3 * pixel + 2])  # the return, lidar frame
    along = (x * ray[0] + y * ray[1] + z * ray[2]) / np.maximum(return_m, 1e-9)
    keep = np.flatnonzero(rho * rho - along * along < config.pass_tolerance_m**2)  # the ray passes the centroid
    pair, x, y, z, pixel, return_m, along = (a[keep] for a in (pair, x, y, z, pixel, return_m, along))
    ray = tuple(a[keep] for a in ray)
    beyond: float | np.ndarray = margin
    if config.grazing_slack:
        offset = config.pass_tolerance_m + along * np.tan(np.deg2rad(config.pose_angle_deg))
        sine = stack.sin_grazing.reshape(-1)[pixel].astype(np.float64)
        beyond = np.maximum(margin, offset / np.maximum(sine, 1e-3))
    through = return_m > along + beyond
    if stack.nearest_around_m is not None:  # the rays around too, by the same along + beyond
        through &= stack.nearest_around_m.reshape(-1)[pixel] > along + beyond
    if normals_world is not None:
        # How far in front of the voxel's surface the ray passes: n . (closest point of the ray - c).
        m = np.matmul(normals_world[None], R).reshape(-1, 3)[pair]
        m_ray = (m[:, 0] * ray[0] + m[:, 1] * ray[1] + m[:, 2] * ray[2]) / np.maximum(return_m, 1e-9)
        in_front = along * m_ray - (m[:, 0] * x + m[:, 1] * y + m[:, 2] * z)
        through &= in_front <= config.surface_tolerance_m + along * np.tan(np.deg2rad(config.surface_angle_deg))
    voxel = pair % n_voxels
    misses = np.bincount(voxel[through], minlength=n_voxels)
    hits = np.bincount(voxel[np.abs(return_m - along) <= margin], minlength=n_voxels)
    return hits, misses


def outvoted_voxels(
    static_keys: np.ndarray,
    static_counts: np.ndarray,
    dynamic_keys: np.ndarray,
    dynamic_counts: np.ndarray,
    vote_ratio: float,
) -> np.ndarray:
    """The map voxels (sorted keys) holding more than ``vote_ratio`` times as many points judged
    dynamic as points judged static, over the whole run (each key array sorted and unique)."""
    _, in_static, in_dynamic = np.intersect1d(static_keys, dynamic_keys, assume_unique=True, return_indices=True)
    outvoted = dynamic_counts[in_dynamic] > vote_ratio * static_counts[in_static]
    return static_keys[in_static[outvoted]]


@dataclass(frozen=True, slots=True)
class _WaitingSweep:
    """A sweep waiting for the probes of its window, grouped by voxel.

    Attributes:
        index: its place in the input (0, 1, ...).
        origin_world: (3,) its sensor position.
        keys: (V,) sorted voxel keys; ``sums``: (V,5) per voxel the sums of x, y, z and intensity
            and the count (:attr:`FilteredSweep.voxel_sums`).
        mean_normals: (V,3) float32 per voxel the mean of its points' unit surface normals (world frame,
            turned towards the sensor; 0 for a point whose normal is unknown), or None.
        points: with ``per_point``, the (N,3) world points, (N,) float32 intensities and (N,) int32
            voxel of each point; None without.
    """

    index: int
    origin_world: np.ndarray
    keys: np.ndarray
    sums: np.ndarray
    mean_normals: np.ndarray | None
    points: tuple[np.ndarray, np.ndarray, np.ndarray] | None


class DynamicFilter:
    """Decides each sweep against the probes of a window around it; call :meth:`add` per sweep in
    time order, then :meth:`flush`.

    A voxel keeps its decision for the next ``reuse_scans`` sweeps, ``window_scans`` when it was
    clearly static (hit by at least two probes, seen through by none): static structure is seen again
    by every sweep, and only the voxels new to the view, or whose decision ran out, are tested.

    Args:
        config: the ``[dynamic]`` section.
        elevation_deg: the sensor's ascending beam elevations (index = ring).
        n_columns: the sensor's azimuth cells per sweep (the probes' columns).
        per_point: the decided sweeps carry their points and a flag per point; without it only their
            voxels (what a voxel map of ``config.voxel_m`` takes: a waiting sweep then holds about a
            third of the memory).
    """

    def __init__(
        self, config: DynamicConfig, elevation_deg: tuple[float, ...], n_columns: int, *, per_point: bool = True
    ) -> None:
        self.config = config
        self.per_point = per_point
        self._elevation_rad = np.deg2rad(np.asarray(elevation_deg, dtype=np.float64))
        self._n_bins = int(n_columns)
        self._sweeps: deque[_WaitingSweep] = deque()
        self._probe_slots = 2 * (config.window_scans // config.probe_every) + 3
        self._stack = ProbeStack(self._probe_slots, len(self._elevation_rad), self._n_bins)
        self._slot_sweep = np.full(self._probe_slots, -(10**9), np.int64)  # sweep index of each slot's probe
        self._n_probes = 0
        # (sorted voxel keys, dynamic flags, last sweep index each decision holds for) of recent sweeps
        self._recent: deque[tuple[np.ndarray, np.ndarray, np.ndarray]] = deque(maxlen=config.reuse_scans)
        self._ground = _GroundGrid()
        self._n_added = 0

    def add(self, sweep: PlacedSweep) -> list[FilteredSweep]:
        """Take the next sweep; returns the sweeps whose window is now complete (oldest first)."""
        index = self._n_added
        self._n_added += 1
        if index % self.config.probe_every == 0:
            self._ground.note(sweep.points_world)
            slot = self._n_probes % self._probe_slots
            self._stack.put(slot, SweepProbe.of(sweep, len(self._elevation_rad), self._n_bins))
            self._slot_sweep[slot] = index
            self._n_probes += 1
        self._sweeps.append(self._grouped(index, sweep))
        decided = []
        while self._sweeps and self._sweeps[0].index + self.config.window_scans <= index:
            decided.append(self._decide())
        return decided

    def flush(self) -> list[FilteredSweep]:
        """End of input: decide the sweeps still waiting (their window ends early)."""
        return [self._decide() for _ in range(len(self._sweeps))]

    def _grouped(self, index: int, sweep: PlacedSweep) -> _WaitingSweep:
        """``sweep`` grouped by voxel, with the surface normals of its voxels when they are used:
        what waits for its window (its lidar frame points go; its world points too without
        ``per_point``)."""
        keys, inverse = key_groups(voxel_keys(sweep.points_world, self.config.voxel_m))
        inverse = inverse.reshape(-1).astype(np.int32)
        counts = np.bincount(inverse, minlength=keys.size)
        sums = np.column_stack(
            [
                group_sums(inverse, sweep.points_world, keys.size),
                np.bincount(inverse, weights=sweep.intensity, minlength=keys.size),
                counts,
            ]
        )
        mean_normals = None
        if self.config.surface_side:
            normals = point_normals(sweep.points_lidar, sweep.ring, len(self._elevation_rad), self._n_bins)
            normals = normals @ sweep.T_world_lidar[:3, :3].T
            mean_normals = (group_sums(inverse, normals, keys.size) / counts[:, None]).astype(np.float32)
        origin = sweep.T_world_lidar[:3, 3].copy()
        points = (sweep.points_world, sweep.intensity, inverse) if self.per_point else None
        return _WaitingSweep(index, origin, keys, sums, mean_normals, points)

    def _decide(self) -> FilteredSweep:
        waiting = self._sweeps.popleft()
        index, keys, sums = waiting.index, waiting.keys, waiting.sums
        config = self.config
        dynamic, valid_until = self._recalled(keys, index)
        test = np.flatnonzero(valid_until < 0)
        centroids = sums[test, :3] / sums[test, 4:5]
        # The band widens with range: a small tilt error of a pose lifts far ground by metres times it.
        reach = np.linalg.norm(centroids - waiting.origin_world, axis=1)
        above = self._ground.height_above(centroids) > config.ground_band_m + config.ground_band_per_m * reach
        test, centroids = test[above], centroids[above]
        normals = None if waiting.mean_normals is None else waiting.mean_normals[test]
        offset = self._slot_sweep - index
        slots = np.flatnonzero((offset != 0) & (np.abs(offset) <= config.window_scans))
        hits, misses = voxel_evidence(centroids, self._stack, slots, self._elevation_rad, config, normals)
        dynamic[test] = (misses >= config.min_misses) & (misses >= config.miss_ratio * hits)
        if config.cluster_share > 0.0:
            dynamic[test] |= mostly_dynamic_clusters(keys[test], dynamic[test], hits + misses > 0, config.cluster_share)
        valid_until[valid_until < 0] = index + config.reuse_scans
        # clearly static: hit twice, seen through by no probe, not in a cluster gone whole
        valid_until[test[(hits >= 2) & (misses == 0) & ~dynamic[test]]] = index + config.window_scans
        self._recent.appendleft((keys, dynamic, valid_until))
        if waiting.points is None:
            return FilteredSweep(keys, sums, dynamic)
        points, intensity, inverse = waiting.points
        return FilteredSweep(keys, sums, dynamic, points, intensity, dynamic[inverse])

    def _recalled(self, keys: np.ndarray, index: int) -> tuple[np.ndarray, np.ndarray]:
        """The decisions of recent sweeps on ``keys`` (sorted) that still hold: (V,) dynamic flags and
        the last sweep index each holds for (-1: none holds, test it)."""
        dynamic = np.zeros(keys.size, bool)
        valid_until = np.full(keys.size, -1, np.int64)
        for recent_keys, recent_dynamic, recent_valid in self._recent:  # newest first
            open_ = np.flatnonzero(valid_until < 0)
            if not open_.size:
                break
            if not recent_keys.size:
                continue
            at = np.minimum(np.searchsorted(recent_keys, keys[open_]), recent_keys.size - 1)
            found = (recent_keys[at] == keys[open_]) & (recent_valid[at] >= index)
            dynamic[open_[found]] = recent_dynamic[at[found]]
            valid_until[open_[found]] = recent_valid[at[found]]
        return dynamic, valid_until


def mostly_dynamic_clusters(keys: np.ndarray, dynamic: np.ndarray, evidence: np.ndarray, share: float) -> np.ndarray:
    """(V,) bool: the voxels of the connected clusters (26-neighbourhood) of a sweep's voxels whose
    voxels with evidence are at least ``share`` dynamic (and one is).

    A moving car's sides are seen through once it has gone, its roof is not (the rays that pass
    over a roof do not go through it, and none passes below it from the side it was seen): the
    roof goes with the rest of the car.

    Args:
        keys: (V,) sorted voxel keys (:func:`~lidar3d.mapping.voxel.voxel_keys`).
        dynamic: (V,) bool, the voxel was seen through.
        evidence: (V,) bool, some probe hit or saw through it.
    """
    n = keys.size
    if not n or not dynamic.any():
        return np.zeros(n, bool)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    # The 13 neighbours after a voxel in key order: each pair once.
    steps = [voxel_key_step(*d) for d in itertools.product((-1, 0, 1), repeat=3)]
    rows, columns = [], []
    for step in (s for s in steps if s > 0):
        neighbour = keys + step
        at = np.minimum(np.searchsorted(keys, neighbour), n - 1)
        found = np.flatnonzero(keys[at] == neighbour)
        rows.append(found)
        columns.append(at[found])
    row, column = np.concatenate(rows), np.concatenate(columns)
    graph = coo_matrix((np.ones(row.size, np.int8), (row, column)), shape=(n, n))
    _, cluster = connected_components(graph, directed=False)
    n_dynamic = np.bincount(cluster, weights=dynamic)
    n_evidence = np.bincount(cluster, weights=evidence)
    return ((n_dynamic >= share * n_evidence) & (n_dynamic > 0))[cluster]


class _GroundGrid:
    """The lowest point height seen in every ``_GROUND_CELL_M`` cell, in square tiles of cells."""

    _TILE = 256  # cells per tile side

    def __init__(self) -> None:
        self._tiles: dict[int, np.ndarray] = {}

    def note(self, points_world: np.ndarray) -> None:
        """Lower the cells under ``points_world`` (N,3) to their lowest point."""
        if not len(points_world):
            return
        cell = np.floor(points_world[:, :2] / _GROUND_CELL_M).astype(np.int64)
        flat = (cell[:, 0] << 32) + cell[:, 1]
        order = np.lexsort((points_world[:, 2], flat))
        first = order[np.r_[True, flat[order][1:] != flat[order][:-1]]]  # the lowest point of each cell
        cell, z = cell[first], points_world[first, 2]
        for key, rows in self._by_tile(cell):
            tile = self._tiles.setdefault(key, np.full((self._TILE, self._TILE), np.inf, np.float32))
            i, j = (cell[rows] % self._TILE).T
            tile[i, j] = np.minimum(tile[i, j], z[rows])

    def height_above(self, points_world: np.ndarray) -> np.ndarray:
        """(N,) height of each point above the lowest point of the 3x3 cells around it (inf: none)."""
        if not len(points_world):
            return np.zeros(0)
        cell = np.floor(points_world[:, :2] / _GROUND_CELL_M).astype(np.int64)
        unique, inverse = key_groups((cell[:, 0] << 32) + (cell[:, 1] + (1 << 31)))
        cell = np.column_stack([unique >> 32, (unique & 0xFFFFFFFF) - (1 << 31)])
        low = np.full(len(unique), np.inf)
        for shift in ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 0), (0, 1), (1, -1), (1, 0), (1, 1)):
            shifted = cell + shift
            for key, rows in self._by_tile(shifted):
                tile = self._tiles.get(key)
                if tile is not None:
                    i, j = (shifted[rows] % self._TILE).T
                    low[rows] = np.minimum(low[rows], tile[i, j])
        return points_world[:, 2] - low[inverse.reshape(-1)]

    def _by_tile(self, cell: np.ndarray):
        """(tile key, row indices) of the cells of each tile."""
        tile = cell // self._TILE
        key = (tile[:, 0] << 32) + tile[:, 1]
        if key.min() == key.max():
            yield int(key[0]), slice(None)
            return
        order = np.argsort(key, kind="stable")
        sorted_key = key[order]
        bounds = np.flatnonzero(np.r_[True, sorted_key[1:] != sorted_key[:-1], True])
        for a, b in itertools.pairwise(bounds):
            yield int(sorted_key[a]), order[a:b]
