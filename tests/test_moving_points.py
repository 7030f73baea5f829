"""The tracker's moving-point test: points where the latest keyframes' rays saw through."""

from __future__ import annotations

import dataclasses

import numpy as np

from lidar3d.config import Config, MappingConfig
from lidar3d.features.records import FeatureCloud, FeatureSet
from lidar3d.mapping.moving_points import MovingPoints
from lidar3d.mapping.registration import PosePrior
from lidar3d.mapping.sweep import SweepFeatures

MODEL = Config().sensor.resolved_model
CONFIG = dataclasses.replace(Config(), mapping=dataclasses.replace(MappingConfig(), moving_probe_keyframes=8))


def _ray(ring: int, azimuth_deg: float, range_m: float) -> np.ndarray:
    """(3,) the point at ``range_m`` along beam ``ring`` at ``azimuth_deg``, lidar frame."""
    e, a = np.radians(MODEL.elevation_deg[ring]), np.radians(azimuth_deg)
    return range_m * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def _cloud(points: np.ndarray, rings: np.ndarray) -> FeatureCloud:
    return FeatureCloud(points.reshape(-1, 3), rings.astype(np.uint16), np.zeros(len(rings)))


def _sweep(less_flat: FeatureCloud, ground: FeatureCloud | None = None) -> SweepFeatures:
    none = FeatureCloud.empty()
    features = FeatureSet(stamp_ns=0, sharp=none, less_sharp=none, flat=none, less_flat=less_flat, outliers=none)
    return SweepFeatures(features, ground or none)


def _wall_sweep() -> SweepFeatures:
    """Every beam of azimuths -25..25 deg returning from a wall across x = 10 m."""
    rings, azimuths = np.meshgrid(np.arange(len(MODEL.elevation_deg)), np.arange(-25.0, 25.0, 0.2), indexing="ij")
    points = []
    for ring, azimuth in zip(rings.ravel(), azimuths.ravel()):
        direction = _ray(int(ring), float(azimuth), 1.0)
        points.append(direction * (10.0 / direction[0]))
    return _sweep(_cloud(np.array(points), rings.ravel()))


def _probes(n_keyframes: int = 4) -> MovingPoints:
    moving = MovingPoints.of_config(CONFIG)
    assert moving is not None
    for _ in range(n_keyframes):  # keyframes at the origin, all seeing the wall
        moving.without_moving(_wall_sweep(), _wall_sweep(), None)
        moving.add_keyframe(np.eye(4))
    return moving


def test_space_seen_through_is_moving_the_surface_and_what_it_hides_are_not():
    moving = _probes()
    ring, azimuth = 8, 3.1  # a beam that reached the wall at 10 m (x)
    direction = _ray(ring, azimuth, 1.0)
    in_front = direction * (7.0 / direction[0])  # where a car now stands: rays passed it
    on_wall = direction * (10.0 / direction[0])
    behind = direction * (13.0 / direction[0])  # hidden by the wall: no evidence
    nowhere = _ray(ring, 90.0, 7.0)  # no return in that direction: no evidence either
    points = np.array([in_front, on_wall, behind, nowhere])
    assert moving.moving(points, np.eye(4)).tolist() == [True, False, False, False]
    # the same points seen from 2 m further on (the car keeps its place in front of the vehicle)
    T = np.eye(4)
    T[0, 3] = 2.0
    assert moving.moving(points - [2.0, 0.0, 0.0], T).tolist() == [True, False, False, False]
    moving.clear()
    assert not moving.moving(points, np.eye(4)).any()  # a loop closure moved the keyframes


def test_one_keyframe_is_not_evidence_enough():
    moving = _probes(n_keyframes=1)
    direction = _ray(8, 3.1, 1.0)
    assert not moving.moving(direction[None] * 7.0, np.eye(4)).any()


def test_without_moving_drops_the_moving_points_and_keeps_the_ground():
    moving = _probes()
    direction = _ray(8, 3.1, 1.0)
    car = np.array([direction * (7.0 / direction[0]), direction * (10.0 / direction[0])])
    ground = _cloud(np.array([[5.0, 0.0, -1.7]]), np.array([0]))
    sweep = _sweep(_cloud(car, np.array([8, 8])), ground)
    fired, deskewed = moving.without_moving(sweep, sweep, np.eye(4))
    assert len(fired.features.less_flat) == len(deskewed.features.less_flat) == 1
    np.testing.assert_allclose(deskewed.features.less_flat.points[0], car[1])
    assert len(deskewed.coarse_ground) == 1
    unchanged = moving.without_moving(sweep, sweep, None)  # the first scan: nothing to test against
    assert unchanged == (sweep, sweep)


def test_the_test_is_off_unless_asked_for():
    assert MovingPoints.of_config(Config()) is None
    assert MovingPoints.of_config(CONFIG) is not None


def test_an_uncertain_pose_needs_more_than_its_uncertainty_to_see_through():
    moving = _probes()
    direction = _ray(8, 3.1, 1.0)
    three_m_in_front = direction * (7.0 / direction[0])
    assert moving.moving(three_m_in_front[None], np.eye(4)).all()
    moving.note_pose_covariance(np.diag([1e-4] * 3 + [1.0, 0.04, 0.01]))  # 1 m along x: a drifting guess
    assert not moving.moving(three_m_in_front[None], np.eye(4)).any()  # 3 m < 0.4 m + 3 sigma
    moving.note_pose_covariance(np.diag([1e-4] * 3 + [0.01, 0.01, 0.01]))  # 10 cm
    assert moving.moving(three_m_in_front[None], np.eye(4)).all()
    moving.note_pose_covariance(None)
    assert moving.moving(three_m_in_front[None], np.eye(4)).all()


def _side_wall_sweep(y_m: float = 3.0) -> SweepFeatures:
    """Every beam of azimuths 3..40 deg returning from a wall along the street at y = ``y_m``
    (what the vehicle drives beside: seen ever more obliquely farther ahead)."""
    rings, azimuths = np.meshgrid(np.arange(len(MODEL.elevation_deg)), np.arange(3.0, 40.0, 0.2), indexing="ij")
    points = []
    for ring, azimuth in zip(rings.ravel(), azimuths.ravel()):
        direction = _ray(int(ring), float(azimuth), 1.0)
        points.append(direction * (y_m / direction[1]))
    return _sweep(_cloud(np.array(points), rings.ravel()))


def _yawed(deg: float) -> np.ndarray:
    """(4,4) a pose turned by ``deg`` about z."""
    T = np.eye(4)
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def test_a_guess_turned_within_its_uncertainty_does_not_see_through_a_far_wall():
    moving = MovingPoints.of_config(CONFIG)
    assert moving is not None
    for _ in range(4):  # keyframes at the origin, all seeing the wall beside the street
        moving.without_moving(_side_wall_sweep(), _side_wall_sweep(), None)
        moving.add_keyframe(np.eye(4))
    direction = _ray(8, 5.7, 1.0)
    on_wall = (direction * (3.0 / direction[1]))[None]  # 30 m ahead, on the wall
    # a guess 2 deg off in yaw (a turn's onset the prediction missed) puts it 1 m into the
    # street, where the keyframes' rays (and the rays around them) went 14 m on
    assert moving.moving(on_wall, _yawed(-2.0)).all()

    moving.note_pose_covariance(None, np.radians(0.5) ** 2)  # the vehicle model's yaw over one step
    assert not moving.moving(on_wall, _yawed(-1.0)).any()
    assert not moving.moving(on_wall, _yawed(-2.0)).any()  # within three sigmas
    moving.note_pose_covariance(None, np.radians(0.1) ** 2)
    assert moving.moving(on_wall, _yawed(-2.0)).all()  # beyond them
    prior = PosePrior(np.eye(4), np.diag([1e4] * 3 + [1e10, 1e10, np.radians(0.5) ** -2]))  # [t, r]
    assert np.isclose(prior.rotation_variance_rad2(), np.radians(0.5) ** 2)
    pose_covariance = np.diag([np.radians(0.5) ** 2] * 3 + [1e-6] * 3)  # [w, v]: the pose's own yaw
    moving.note_pose_covariance(pose_covariance)
    assert not moving.moving(on_wall, _yawed(-2.0)).any()
    # a guess whose rotation is not known at all (three sigmas past 90 deg) tells nothing moving
    lost = np.diag([np.radians(40.0) ** 2] * 3 + [1e-6] * 3)
    moving.note_pose_covariance(lost)
    assert not moving.moving(on_wall, _yawed(-2.0)).any()


def test_a_point_at_a_poles_edge_is_not_moving_a_point_in_open_space_is():
    """Keyframes see a pole 5 m ahead in one column, before a wall at 10 m; the ray of the next
    column passes the pole's edge and returns from the wall, but the ray beside it hit the pole."""
    rings, azimuths = np.meshgrid(np.arange(len(MODEL.elevation_deg)), np.arange(-25.0, 25.0, 0.2), indexing="ij")
    pole_azimuth = azimuths[0][np.argmin(np.abs(azimuths[0] - 3.1))]
    points = []
    for ring, azimuth in zip(rings.ravel(), azimuths.ravel()):
        direction = _ray(int(ring), float(azimuth), 1.0)
        points.append(direction * ((5.0 if azimuth == pole_azimuth else 10.0) / direction[0]))
    sweep = _sweep(_cloud(np.array(points), rings.ravel()))
    moving = MovingPoints.of_config(CONFIG)
    assert moving is not None
    for _ in range(4):
        moving.without_moving(sweep, sweep, None)
        moving.add_keyframe(np.eye(4))
    beside = _ray(8, float(pole_azimuth) + 0.2, 1.0)
    edge = beside * (5.0 / beside[0])  # in the next column, at the pole's range
    assert not moving.moving(edge[None], np.eye(4)).any()
    open_space = _ray(8, float(pole_azimuth) + 1.0, 1.0)
    assert moving.moving((open_space * (5.0 / open_space[0]))[None], np.eye(4)).all()
