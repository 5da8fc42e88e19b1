"""Moving talkers: walking trajectories, turned and moving arrays, their simulation and truth."""
from __future__ import annotations

import math

import numpy as np
import pytest

from doabench.acoustics.render import render_scene
from doabench.acoustics.room import Room
from doabench.acoustics.scenes import Scene, SceneDistribution, sample_scene
from doabench.acoustics.simulators import get_simulator
from doabench.acoustics.trajectories import sample_directions
from doabench.acoustics.walks import check_rotations, rotation_matrix, sample_walk
from doabench.arrays import get_array
from doabench.corpora.speech import EmbeddedSpeechSource
from doabench.errors import ConfigError
from doabench.geometry import grid_unit_vectors, great_circle_error, normalize

SPEECH = EmbeddedSpeechSource()
WALK = SceneDistribution(walk_p=1.0, array_yaw=(-180.0, 180.0), array_pitch=(-30.0, 30.0), array_roll=(-15.0, 15.0))
TURN = WALK.replace(array_motion_p=1.0, array_speed=(0.0, 0.3))


def _scene(trajectory, rotation=None, path=None, static=False) -> Scene:
    nao = get_array("nao")
    return Scene(room=Room((8.0, 6.0, 3.0), 0.0, (1.0,) * 6), snr_db=30.0, array_position=np.array([4.0, 3.0, 1.2]),
                 array_name="nao", mic_positions=np.array(nao.positions), trajectory=np.asarray(trajectory),
                 static=static, seed=0, duration_s=20.0, array_rotation=rotation, array_path=path)


def test_a_talker_on_a_known_arc_has_the_arcs_angular_speed():
    # 1 m/s on a 2 m circle round the array, at the array's height: 1/2 rad/s = 28.65 deg/s
    S, radius, speed = 156, 2.0, 1.0
    t = (np.arange(S) + 0.5) * 20.0 / S
    a = speed / radius * t
    points = np.stack([4.0 + radius * np.cos(a), 3.0 + radius * np.sin(a), np.full(S, 1.2)], 1)
    scene = _scene(points)
    assert np.allclose(scene.speed_deg_s, math.degrees(speed / radius), rtol=1e-3)
    # seen from a turned array the angular speed is the same
    turned = _scene(points, rotation=rotation_matrix(40.0, 20.0, -10.0))
    assert np.allclose(turned.speed_deg_s, scene.speed_deg_s, rtol=1e-9)


def test_a_rotated_arrays_truth_is_the_room_direction_rotated_into_the_array_frame():
    rot = rotation_matrix(75.0, -25.0, 10.0)
    points = np.array([[6.0, 4.5, 1.7]] * 4)
    scene = _scene(points, rotation=rot, static=True)
    room_dir = normalize(points[0] - scene.array_position)
    truth = scene.sample_directions(100)
    assert np.allclose(truth, rot.T @ room_dir)
    # the microphones turn with the array
    assert np.allclose(scene.mic_room_positions, scene.array_position + scene.mic_positions @ rot.T)


def test_a_moving_arrays_truth_uses_the_pose_of_each_point():
    S = 10
    rots = rotation_matrix(np.linspace(0, 90, S), np.zeros(S), np.zeros(S))
    path = np.stack([np.linspace(3.0, 4.0, S), np.full(S, 3.0), np.full(S, 1.2)], 1)
    points = np.repeat([[6.0, 5.0, 1.5]], S, axis=0)
    scene = _scene(points, rotation=rots, path=path, static=True)
    per_point = sample_directions(points, path, S, rots)
    for i in range(S):
        assert np.allclose(per_point[i], rots[i].T @ normalize(points[i] - path[i]))
    assert scene.mic_room_positions.shape == (S, 12, 3)
    assert np.allclose(scene.mic_room_positions[3], path[3] + scene.mic_positions @ rots[3].T)


def test_walks_stay_in_the_room_at_their_distance_and_speed():
    for seed in range(30):
        sc = sample_scene(WALK, seed)
        dims = np.asarray(sc.room.dims)
        assert sc.trajectory_params["family"] == "walk" and not sc.static
        assert np.all(sc.trajectory >= WALK.wall_margin - 1e-9) and np.all(sc.trajectory <= dims - WALK.wall_margin + 1e-9)
        horizontal = np.linalg.norm(sc.trajectory[:, :2] - sc.array_position[:2], axis=1)
        assert np.all(horizontal >= 1.0 - 1e-9) and np.all(horizontal <= 4.0 + 1e-9)
        steps = np.linalg.norm(np.diff(sc.trajectory, axis=0), axis=1)
        v = sc.trajectory_params["speed"]
        assert 0.3 <= v <= 1.5 and np.all(steps <= v * 20.0 / 156 + 1e-9)
        check_rotations(sc.array_rotation)
    # walking talkers are a different family from the paper's: the median speed is far above sim-grid's
    speeds = [np.median(sample_scene(WALK, s).speed_deg_s) for s in range(30)]
    assert np.median(speeds) > 10.0


def test_walks_are_a_pure_function_of_the_seed_and_leave_other_parts_alone():
    a, b = sample_scene(TURN, 3), sample_scene(TURN, 3)
    assert a == b and Scene.from_dict(a.to_dict()) == a
    paper = sample_scene(SceneDistribution(), 3)
    assert a.room == sample_scene(SceneDistribution(walk_p=1.0), 3).room
    assert np.array_equal(paper.array_position, a.array_position)
    # the paper's distribution names none of the moving-talker fields, so earlier tasks are unchanged
    assert not any(k.startswith(("walk", "array_yaw", "array_motion")) for k in SceneDistribution().to_dict())


def test_a_moving_array_stays_in_the_room_and_clear_of_the_talker():
    for seed in range(20):
        sc = sample_scene(TURN, seed)
        assert sc.moving_array and sc.array_path.shape == (156, 3)
        check_rotations(sc.array_rotation)
        horizontal = np.linalg.norm(sc.trajectory[:, :2] - sc.array_path[:, :2], axis=1)
        assert horizontal.min() >= 1.0 - 1e-9
        assert np.linalg.norm(np.diff(sc.array_path, axis=0), axis=1).max() <= 0.3 * 20 / 156 + 1e-9


@pytest.mark.parametrize("native", ["1", "0"])
def test_per_point_microphones_equal_the_shared_array_when_the_array_stands_still(native, monkeypatch):
    from doabench.acoustics import native as native_module

    monkeypatch.setenv("DOABENCH_NATIVE", native)
    native_module.reload()
    room = Room((6.0, 5.0, 3.0), 0.4, (1.0,) * 6)
    rng = np.random.default_rng(0)
    src = rng.uniform([1, 1, 1], [5, 4, 2], (6, 3))
    mics = np.array([[3.0, 2.5, 1.5], [3.05, 2.5, 1.5], [3.0, 2.55, 1.5], [3.0, 2.5, 1.55]])
    sim = get_simulator("builtin")
    shared = sim.rirs(room, src, mics, 16000, seed=1)
    per_point = sim.rirs(room, src, np.repeat(mics[None], 6, axis=0), 16000, seed=1)
    assert np.abs(shared - per_point).max() <= 1e-5 * np.abs(shared).max()
    # a moving array: each point's early part is that point's own static simulation (to 1e-3 of
    # the peak: the batch computes in coordinates about the centre of all poses, so float32
    # arrival times round to other 1/128-sample phases than about one pose's centre)
    moving = np.stack([mics + [0.05 * s, 0.0, 0.0] for s in range(6)])
    parts = sim.rirs(room, src, moving, 16000, seed=1)
    n_early = int(round(room.diffuse_start() * 16000))
    for s in range(6):
        alone = sim.rirs(room, src[s : s + 1], moving[s], 16000, seed=1)[0]
        assert np.abs(parts[s, :, :n_early] - alone[:, :n_early]).max() <= 2e-3 * np.abs(alone).max()
    native_module.reload()


def test_pyroomacoustics_takes_per_point_microphones():
    room = Room((6.0, 5.0, 3.0), 0.3, (1.0,) * 6)
    src = np.array([[1.0, 1.0, 1.2], [1.5, 1.2, 1.2]])
    mics = np.array([[3.0, 2.5, 1.5], [3.05, 2.5, 1.5]])
    sim = get_simulator("pyroomacoustics")
    shared = sim.rirs(room, src, mics, 16000, seed=1)
    per_point = sim.rirs(room, src, np.repeat(mics[None], 2, axis=0), 16000, seed=1)
    assert np.array_equal(shared, per_point)


def _srp_error_deg(dist: SceneDistribution, seed: int) -> float:
    from doabench.features import FeatureExtractor
    from doabench.framing import FrameSpec

    scene = sample_scene(dist, seed, SPEECH)
    ep = render_scene(scene, SPEECH)
    feats = FeatureExtractor(scene.array, kinds=("srp",), resolution=(32, 64))(ep.audio[None], ep.sample_vad[None])
    srp = np.asarray(feats["srp"][0])
    vad = np.asarray(feats["vad"][0], dtype=bool)
    est = grid_unit_vectors(32, 64).reshape(-1, 3)[srp.reshape(len(srp), -1).argmax(-1)]
    truth = ep.frame_truth(FrameSpec())["directions"][: len(srp)]
    return float(np.median(np.degrees(great_circle_error(est[vad], truth[vad]))))


@pytest.mark.parametrize("moving", [False, True])
def test_srp_of_a_turned_or_turning_array_peaks_at_the_array_frame_truth(moving):
    # anechoic: the map's maximum is the plane wave's direction in the array frame
    dist = TURN if moving else WALK
    dist = dist.replace(t60=(0.0, 0.0), snr=(30.0, 30.0), duration_s=6.0, n_points=47, walk_speed=(0.3, 0.5))
    assert _srp_error_deg(dist, 2) < 5.6  # the 32x64 grid spacing


@pytest.mark.parametrize("change, match", [
    (dict(walk_p=1.0, walk_height=(3.5, 4.0), room_max=(10.0, 8.0, 3.0)), "walk_height"),
    (dict(walk_p=1.0, walk_distance=(12.0, 13.0)), "walk_distance"),
    (dict(array_yaw=(-200.0, 0.0)), "array_yaw"),
    (dict(array_motion_p=1.5), "array_motion_p"),
    (dict(walk_speed=(-1.0, 1.0)), "walk_speed"),
])
def test_bad_moving_talker_parameters_name_the_field(change, match):
    with pytest.raises(ConfigError, match=match):
        SceneDistribution(**change)


def test_a_walk_that_cannot_fit_the_room_and_a_pose_that_is_not_a_rotation_are_config_errors():
    with pytest.raises(ConfigError, match="walk_speed"):
        # 4 m/s: a 0.5 m step per trajectory point, too far to walk 1 m from the array
        sample_walk(np.random.default_rng(0), np.array([3.0, 3.0, 2.5]), np.array([0.5, 0.5, 1.0]),
                    distance=(1.0, 1.1), speed=(4.0, 4.1), max_tries=5)
    with pytest.raises(ConfigError, match="array rotation"):
        check_rotations(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ConfigError, match="not a rotation"):
        _scene(np.array([[6.0, 4.5, 1.7]]), rotation=2 * np.eye(3), static=True)
    with pytest.raises(ConfigError, match="array centre"):
        _scene(np.array([[6.0, 4.5, 1.7]] * 3), path=np.array([[4.0, 3.0, 1.2], [9.0, 3.0, 1.2], [4.0, 3.0, 1.2]]),
               static=True)
