"""Microphone arrays, frames and angle conventions."""
import json

import numpy as np
import pytest

from doabench.arrays import get_array, load_array_file
from doabench.errors import ConfigError, NotFoundError
from doabench.framing import FrameSpec, frame_mean_directions, frame_signal, frame_vad, n_frames
from doabench.geometry import angles_to_unit, grid_angles, unit_to_angles


def test_nao_array_matches_the_locata_documentation():
    nao = get_array("nao")
    assert nao.n_mics == 12 and not nao.planar
    assert get_array("benchmark2").positions.tolist() == nao.positions.tolist()
    np.testing.assert_allclose(nao.positions[0], [-0.028, 0.030, -0.040])
    np.testing.assert_allclose(nao.positions[11], [0.035, 0.025, 0.039])
    d = np.linalg.norm(nao.positions[:, None] - nao.positions[None], axis=-1)
    # the paper: minimum and maximum inter-microphone distances 1.3 cm and 12.1 cm
    assert d[np.triu_indices(12, 1)].min() == pytest.approx(0.013, abs=0.001)
    assert nao.max_distance == pytest.approx(0.121, abs=0.001)
    assert len(nao.pairs) == 66 and nao.max_lag(16000) == 6


def test_json_and_yaml_arrays(tmp_path):
    f = tmp_path / "tri.json"
    f.write_text(json.dumps({"positions": [[0.05, 0, 0], [-0.05, 0, 0], [0, 0.05, 0]]}))
    a = load_array_file(f)
    assert a.name == "tri" and a.planar and a.n_mics == 3
    y = tmp_path / "cube.yaml"
    y.write_text("name: cube\nplanar: false\npositions:\n  - [0, 0, 0]\n  - [0.1, 0, 0]\n  - [0, 0.1, 0.1]\n")
    b = get_array(str(y))
    assert b.name == "cube" and not b.planar


@pytest.mark.parametrize("content,message", [
    ({"positions": [[0, 0, 0]]}, "at least 2 microphones"),
    ({"positions": [[0, 0, 0], [0, 0, float("nan")]]}, "NaN"),
    ({"positions": [[0, 0, 0], [0.1, 0, 0], [0.1, 0, 0]]}, "microphones 2 and 3 are at the same place"),
    ({"positions": [[0, 0], [1, 1]]}, "must be a list of"),
    ({"mics": []}, "'positions'"),
])
def test_bad_array_files_name_file_and_problem(tmp_path, content, message):
    f = tmp_path / "bad.json"
    f.write_text(json.dumps(content))
    with pytest.raises(ConfigError, match=message) as exc:
        load_array_file(f)
    assert "bad" in str(exc.value)


def test_unparseable_and_missing_array_files(tmp_path):
    f = tmp_path / "broken.json"
    f.write_text("{not json")
    with pytest.raises(ConfigError, match="broken.json: cannot parse"):
        load_array_file(f)
    with pytest.raises(NotFoundError, match="does not exist"):
        get_array(str(tmp_path / "nope.json"))
    with pytest.raises(NotFoundError, match="unknown array 'eigen'"):
        get_array("eigen")


def test_frame_rule_gives_the_papers_103_frames():
    spec = FrameSpec()
    assert (spec.window, spec.hop) == (4096, 3072)
    assert spec.n_frames(20 * 16000) == 103
    assert n_frames(4095, 4096, 3072) == 0 and n_frames(4096, 4096, 3072) == 1
    x = np.arange(20000.0)
    frames = frame_signal(x, 4096, 3072)
    assert frames.shape == (n_frames(20000, 4096, 3072), 4096)
    assert frames[2, 0] == 2 * 3072
    import torch

    assert torch.equal(frame_signal(torch.arange(20000.0), 4096, 3072), torch.tensor(np.array(frames), dtype=torch.float32))
    np.testing.assert_allclose(spec.times(2), [4096 / 2 / 16000, (3072 + 2048) / 16000])


def test_frame_vad_needs_more_than_two_thirds_active():
    vad = np.zeros(4096, bool)
    vad[: 4096 * 2 // 3] = True  # exactly 2/3 (rounded down): silent
    assert not frame_vad(vad, 4096, 3072)[0]
    vad[: 4096 * 2 // 3 + 2] = True
    assert frame_vad(vad, 4096, 3072)[0]


def test_frame_mean_direction_handles_azimuth_wrap():
    # azimuth sweeping across +-180 deg inside one window: the mean must stay near 180, not 0
    az = np.linspace(np.radians(170), np.radians(190), 4096)
    dirs = angles_to_unit(np.full_like(az, np.pi / 2), az)
    mean = frame_mean_directions(dirs, 4096, 3072)[0]
    el, a = unit_to_angles(mean)
    assert abs(abs(np.degrees(a)) - 180) < 0.1 and abs(np.degrees(el) - 90) < 1e-6


def test_grid_and_angle_conventions():
    el, az = grid_angles(16, 32)
    assert el[0] == 0 and el[-1] == pytest.approx(np.pi) and len(el) == 16
    assert az[0] == pytest.approx(-np.pi) and az[-1] < np.pi and len(az) == 32
    assert grid_angles(8, 16, planar=True)[0][-1] == pytest.approx(np.pi / 2)
    u = angles_to_unit(np.array([0.0, np.pi / 2]), np.array([0.0, np.pi / 2]))
    np.testing.assert_allclose(u, [[0, 0, 1], [0, 1, 0]], atol=1e-12)  # el = inclination from +z


@pytest.mark.parametrize("content,field", [
    ({"planar": "false", "positions": [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]]}, "planar"),
    ({"planar": 0, "positions": [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]]}, "planar"),
    ({"positions": [[0, 0, 0], [True, 0, 0], [0, 0.1, 0]]}, "positions[1][0]"),
    ({"positions": [[0, 0, 0], ["0.1", 0, 0], [0, 0.1, 0]]}, "positions[1][0]"),
    ({"positions": [[0, 0, 0], [0.1, 0, 0]], "plannar": True}, "plannar"),
    ({"name": 7, "positions": [[0, 0, 0], [0.1, 0, 0]]}, "name"),
    ({"positions": "0 0 0"}, "positions"),
])
def test_array_file_types_are_validated_strictly(tmp_path, content, field):
    """A string "false" used to be taken as True, `true` as a 1 m coordinate, unknown keys ignored."""
    f = tmp_path / "strict.json"
    f.write_text(json.dumps(content))
    with pytest.raises(ConfigError) as exc:
        load_array_file(f)
    assert "strict.json" in str(exc.value) and field in str(exc.value)
    y = tmp_path / "strict.yaml"
    y.write_text("planar: 'false'\npositions: [[0, 0, 0], [0.1, 0, 0]]\n")
    with pytest.raises(ConfigError, match="planar"):
        load_array_file(y)
