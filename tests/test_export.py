"""`doabench export --format onnx`: the full-sequence network, checked against
onnxruntime (the `onnx` extra; skipped without it)."""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from doabench.cli.main import main


@pytest.mark.parametrize("tracker", ["cross3d:4x8", "gcc-cnn1d"])
def test_export_matches_torch_in_onnxruntime(tracker: str, tmp_path: Path, capsys) -> None:
    ort = pytest.importorskip("onnxruntime", reason="the onnx extra: pip install 'doabench[onnx]'")
    onnx = pytest.importorskip("onnx")
    import torch

    import doabench
    from doabench.export_onnx import example_features

    out = tmp_path / "model.onnx"
    assert main(["export", "--tracker", tracker, "--format", "onnx", "--out", str(out)]) == 0
    assert "verified with onnxruntime" in capsys.readouterr().out
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    tr = doabench.make_tracker(tracker)
    assert meta["doabench_tracker"] == tracker and meta["doabench_weights_sha256"] == tr.weights_hash()
    assert json.loads(meta["doabench_observations"]) == tr.observation_spec.to_dict()  # what the input is made of
    assert doabench.ObservationSpec.from_dict(json.loads(meta["doabench_observations"])) == tr.observation_spec
    # Independently: a longer episode through onnxruntime gives the tracker's own track() directions.
    feats = example_features(tr, n_frames=20, seed=5)
    x = tr.episode_input(feats)
    got = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"]).run(None, {"input": x.numpy()})[0][0]
    assert got.shape == (20, 3)
    unit = got / np.linalg.norm(got, axis=1, keepdims=True)
    with torch.no_grad():
        expected = tr.track(feats)
    assert np.abs(unit - expected).max() < 1e-3


def test_export_refuses_untrained_and_classical_trackers(tmp_path: Path, capsys) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert main(["export", "--tracker", "cross3d:12x24", "--out", str(tmp_path / "a.onnx")]) == 2  # none shipped
    assert "no trained weights" in capsys.readouterr().err
    assert main(["export", "--tracker", "srp-max", "--out", str(tmp_path / "b.onnx")]) == 2
    assert "no neural network to export" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_export_names_the_weights_in_its_output_and_metadata(tmp_path: Path, capsys) -> None:
    """The console line and the ONNX metadata name the weights: the shipped name (a copy of a shipped
    file under another name is still that name: it follows the SHA-256) and the file the tracker read."""
    onnx = pytest.importorskip("onnx", reason="the onnx extra: pip install 'doabench[onnx]'")
    from doabench_baselines import weights as W

    copy = tmp_path / "my-copy.safetensors"
    copy.write_bytes((W.SHIPPED_DIR / "cross3d-4x8.safetensors").read_bytes())
    out = tmp_path / "model.onnx"
    assert main(["export", "--tracker", "cross3d:4x8", "--tracker-opt", f"weights={copy}", "--out", str(out)]) == 0
    line = capsys.readouterr().out
    digest = W.sha256_file(copy)
    assert f"cross3d:4x8, weights paper (sha256 {digest[:12]})" in line, line
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert meta["doabench_weights_name"] == "paper" and meta["doabench_weights_file"] == "my-copy.safetensors"
    assert meta["doabench_weights_sha256"] == digest
