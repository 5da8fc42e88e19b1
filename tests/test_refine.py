"""Cross3D's ``refine`` option against physics: a plane wave's direction is found on the fine map
near the network's, never far from it; silent frames and ``refine=off`` pass the network through."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import doabench
from doabench.errors import ConfigError
from doabench.trackers.registry import canonical_tracker
from doabench_baselines.refine import SPEED_FRAMES, MapRefiner, parse_radius, parse_refine, parse_speed
from fixtures.signals import plane_wave

NAO = doabench.get_array("nao")
FRAMES = doabench.FrameSpec()  # 4096-sample windows, as every shipped Cross3D


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1)))


def _tilted(u: np.ndarray, degrees: float, rng) -> np.ndarray:
    """``u`` ``(n, 3)`` turned by ``degrees`` about a random axis perpendicular to each."""
    axis = np.cross(u, rng.standard_normal(u.shape))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    a = np.radians(degrees)
    return u * np.cos(a) + np.cross(axis, u) * np.sin(a)


def _sources(n: int, rng) -> np.ndarray:
    """Directions away from the poles (elevation 40-140 deg), where the NAO array resolves best."""
    el = np.radians(rng.uniform(40, 140, n))
    az = rng.uniform(-np.pi, np.pi, n)
    return np.stack([np.sin(el) * np.cos(az), np.sin(el) * np.sin(az), np.cos(el)], axis=1)


def test_a_coarse_direction_moves_onto_the_plane_wave():
    rng = np.random.default_rng(3)
    truth = _sources(16, rng)
    audio = plane_wave(truth, FRAMES.window, NAO.positions, rng)  # (16, 12, 4096): one frame each
    coarse = _tilted(truth, 8.0, rng)  # a 16x32 network is off by about this much
    refined = MapRefiner(NAO, (64, 128), FRAMES, radius_deg=12.0)(coarse, audio, np.ones(16, bool))
    assert np.all(_angle_deg(coarse, truth) > 7.9)
    # the 64x128 grid steps 2.86 deg in elevation and 2.81 in azimuth: within one cell's diagonal
    assert _angle_deg(refined, truth).max() < 4.0
    np.testing.assert_allclose(np.linalg.norm(refined, axis=1), 1.0, atol=1e-9)


def test_the_fine_maximum_is_looked_for_only_near_the_network():
    """A direction 30 deg from the source stays within the radius of itself: refinement sharpens
    the network's choice, it does not replace it with the map's global peak."""
    rng = np.random.default_rng(4)
    truth = _sources(8, rng)
    audio = plane_wave(truth, FRAMES.window, NAO.positions, rng)
    far = _tilted(truth, 30.0, rng)
    refined = MapRefiner(NAO, (64, 128), FRAMES, radius_deg=10.0)(far, audio, np.ones(8, bool))
    assert _angle_deg(refined, far).max() <= 10.0 + 1e-6
    assert np.all(_angle_deg(refined, truth) < _angle_deg(far, truth))  # moved towards the source


def test_silent_frames_keep_the_network_direction():
    rng = np.random.default_rng(5)
    truth = _sources(6, rng)
    audio = plane_wave(truth, FRAMES.window, NAO.positions, rng)
    coarse = _tilted(truth, 8.0, rng)
    active = np.array([True, False, True, False, False, True])
    refined = MapRefiner(NAO, (64, 128), FRAMES, radius_deg=12.0)(coarse, audio, active)
    np.testing.assert_array_equal(refined[~active], coarse[~active])
    assert _angle_deg(refined[active], truth[active]).max() < 4.0


def _tracker(**options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # untrained-model warning
        return doabench.make_tracker("cross3d:4x8", weights="random", **options)


def test_the_tracker_refines_in_step_and_track_alike_and_reads_audio_only_then():
    plain, refining = _tracker(), _tracker(refine="32x64")
    assert "audio" not in plain.observation_spec.kind_names and "audio" in refining.observation_spec.kind_names
    assert refining.describe()["refine"] == {"resolution": "32x64", "radius_deg": 180 / 3,  # 4x8: one elevation step
                                             "min_speed_deg_s": 0.0}
    rng = np.random.default_rng(6)
    n = 12
    truth = _sources(n, rng)
    ep = {"srp": rng.standard_normal((n, 4, 8)).astype(np.float32), "srp_max": rng.random((n, 2)).astype(np.float32),
          "audio": plane_wave(truth, FRAMES.window, NAO.positions, rng), "vad": np.ones(n, bool)}
    ep["vad"][3] = False
    for t in (plain, refining):
        t.reset(NAO, frame_spec=FRAMES)
    network = plain.track(ep)
    refining.reset(NAO, frame_spec=FRAMES)
    stepped = np.stack([refining.step({k: v[i] for k, v in ep.items()}) for i in range(n)])
    refining.reset(NAO, frame_spec=FRAMES)
    tracked = refining.track(ep)
    np.testing.assert_allclose(stepped, tracked, atol=1e-5)
    np.testing.assert_allclose(tracked[3], network[3], atol=1e-6)  # silent: the network's own
    near = _angle_deg(network, truth) < 55  # within the radius, the source is the fine map's peak
    assert near.sum() >= 2 and np.all(_angle_deg(tracked[near & ep["vad"]], truth[near & ep["vad"]]) < 6.5)


def test_refine_is_part_of_the_run_identity_and_off_is_the_default():
    assert canonical_tracker("cross3d:4x8", {"weights": "random", "refine": "off"})[1] == {"weights": "random"}
    assert canonical_tracker("cross3d:4x8", {"weights": "random", "refine": "64x128"})[1] == {
        "weights": "random", "refine": "64x128"}
    assert canonical_tracker("cross3d:4x8", {"weights": "random", "refine": "64x128", "refine_speed": 0})[1] == {
        "weights": "random", "refine": "64x128"}
    assert canonical_tracker("cross3d:4x8", {"weights": "random", "refine": "64x128", "refine_speed": 30})[1] == {
        "weights": "random", "refine": "64x128", "refine_speed": 30}


@pytest.mark.parametrize("options,message", [
    ({"refine": "fine"}, "refine must be off or a map resolution such as 64x128"),
    ({"refine": "64x128", "refine_radius": "0"}, "refine_radius must be auto or degrees in (0, 90]"),
    ({"refine": "64x128", "refine_radius": "wide"}, "refine_radius must be auto or degrees in (0, 90]"),
    ({"refine": "64x128", "refine_speed": "-1"}, "refine_speed must be degrees per second >= 0"),
    ({"refine": "64x128", "refine_speed": "fast"}, "refine_speed must be degrees per second >= 0"),
    ({"refine": "64x128", "refine_speed": "inf"}, "refine_speed must be degrees per second >= 0"),
    ({"refine_speed": 30}, "refine_speed=30 gates refine, which is off"),
])
def test_bad_refine_options_are_refused_in_one_line(options, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)").replace("]", r"\]")):
        _tracker(**options)


def test_option_parsing():
    assert parse_refine("off") is None and parse_refine(None) is None and parse_refine("64X128") == (64, 128)
    assert parse_radius("auto", (16, 32)) == 12.0 and parse_radius("7.5", (16, 32)) == 7.5
    assert parse_speed(0) == 0.0 and parse_speed("30") == 30.0


def _still_then_turning(still: int = 4, turning: int = 6, step_deg: float = 30.0):
    """Source directions ``(still + turning, 3)``: ``still`` frames at one direction, then turning
    ``step_deg`` a frame about the vertical axis (elevation 70 deg); and the network's directions:
    the sources 8 deg lower (a still source gives a still network direction)."""
    az = np.radians(np.concatenate([np.zeros(still), step_deg * np.arange(1, turning + 1)]))

    def at(elevation_deg: float) -> np.ndarray:
        el = np.radians(elevation_deg)
        return np.stack([np.sin(el) * np.cos(az), np.sin(el) * np.sin(az), np.full_like(az, np.cos(el))], axis=1)

    return at(70.0), at(78.0)


def test_refine_speed_refines_only_where_the_network_turns_fast():
    rng = np.random.default_rng(7)
    truth, network = _still_then_turning()
    audio = plane_wave(truth, FRAMES.window, NAO.positions, rng)
    active = np.ones(len(truth), bool)
    hop_s = FRAMES.hop / FRAMES.fs
    # the network's first turning frame is 29 deg (30 deg of azimuth at elevation 78) from the still
    # one two frames before: 76 deg/s over SPEED_FRAMES = 2 frames of 0.192 s; a still network turns 0 deg/s
    assert SPEED_FRAMES == 2 and 29.0 / (SPEED_FRAMES * hop_s) > 50.0
    gated = MapRefiner(NAO, (64, 128), FRAMES, radius_deg=12.0, min_speed_deg_s=50.0)(network, audio, active)
    np.testing.assert_array_equal(gated[:4], network[:4])
    assert np.all(_angle_deg(network[4:], truth[4:]) > 7.9) and _angle_deg(gated[4:], truth[4:]).max() < 4.0
    always = MapRefiner(NAO, (64, 128), FRAMES, radius_deg=12.0)(network, audio, active)
    assert _angle_deg(always, truth).max() < 4.0  # without the gate every frame moves onto the source
    never = MapRefiner(NAO, (64, 128), FRAMES, radius_deg=12.0, min_speed_deg_s=1000.0)(network, audio, active)
    np.testing.assert_array_equal(never, network)


def test_the_speed_gate_gives_the_same_frames_one_call_each_as_a_whole_episode():
    rng = np.random.default_rng(8)
    truth, network = _still_then_turning(still=3, turning=5, step_deg=12.0)
    audio = plane_wave(truth, FRAMES.window, NAO.positions, rng)
    active = np.ones(len(truth), bool)
    active[4] = False
    whole = MapRefiner(NAO, (64, 128), FRAMES, radius_deg=12.0, min_speed_deg_s=40.0)(network, audio, active)
    one = MapRefiner(NAO, (64, 128), FRAMES, radius_deg=12.0, min_speed_deg_s=40.0)
    stepped = np.concatenate([one(network[i:i + 1], audio[i:i + 1], active[i:i + 1]) for i in range(len(truth))])
    np.testing.assert_array_equal(stepped, whole)
    # 12 deg of azimuth a frame (12 deg of arc at elevation 78): the first turning frame turned 31
    # deg/s over two frames, below the gate; from the second on 61 deg/s, refined but where silent (4)
    refined = np.any(whole != network, axis=1)
    np.testing.assert_array_equal(refined, np.arange(len(truth)) >= 5)
