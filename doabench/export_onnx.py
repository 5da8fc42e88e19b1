"""``doabench export --tracker ID --format onnx --out FILE``: a learned tracker's network as ONNX.

The exported graph is the **full-sequence** model: input ``input`` = the network's input for a
whole episode, ``(batch, ..., frames, ...)`` with the frame axis at position 2 (as every
doabench model lays it out; :meth:`NeuralTracker.episode_input` builds it from the features),
output ``directions`` = ``(batch, frames, 3)`` (not normalised). Batch and frame counts are
dynamic. The file's metadata records the tracker id, the weights (their shipped name, file name
and SHA-256), what the network reads (its ``ObservationSpec`` whole, as ``to_dict()`` stores it)
and the array. With ``onnxruntime`` installed (the
``onnx`` extra: ``pip install 'doabench[onnx]'``) the export is checked against torch on random
features.
"""
from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from doabench.errors import ConfigError, DoabenchError
from doabench.trackers.base import observations_of

FORMATS = ("onnx",)


def example_features(tracker: Any, n_frames: int = 12, seed: int = 0) -> dict[str, np.ndarray]:
    """Features of random audio on the tracker's observations and array: a realistic example input."""
    observations = observations_of(tracker)
    spec = observations.frames
    array = getattr(tracker, "trained_array", None)
    if array is None:
        raise ConfigError(f"tracker {tracker.name!r} has no trained_array to build an example input for")
    samples = spec.window + spec.hop * (n_frames - 1)
    audio = (0.1 * np.random.default_rng(seed).standard_normal((array.n_mics, samples))).astype(np.float32)
    return observations.plan(array).observations(audio, None)


def metadata(tracker: Any, tracker_id: str) -> dict[str, str]:
    """The ONNX file's metadata: what the network is (tracker, weights by name, file and SHA-256,
    whether trained), what it reads (its observation spec, stored whole) and the array."""
    d = tracker.describe()
    weights = d.get("weights")
    return {
        "doabench_tracker": tracker_id,
        # the shipped name ("moving-long"), empty for another file; the file's name either way
        "doabench_weights_name": str(d.get("weights_name") or ""),
        "doabench_weights_file": Path(str(weights)).name if weights else "",
        "doabench_weights_sha256": str(d.get("weights_hash") or ""),
        "doabench_trained": str(bool(d.get("trained", True))).lower(),
        "doabench_observations": json.dumps(observations_of(tracker).to_dict()),
        "doabench_array": str(d.get("array") or ""),
        "doabench_io": "input: network input for a whole episode, frame axis 2; output directions (batch, frames, 3)",
    }


def export_onnx(tracker: Any, out: str | Path, tracker_id: str | None = None, verify: bool = True) -> dict[str, Any]:
    """Write ``tracker``'s network to ``out``; returns ``{"path", "input_shape", "max_abs_diff"}``
    (``max_abs_diff`` None when onnxruntime is not installed)."""
    import torch

    from doabench.files import atomic_path

    network = getattr(tracker, "network", None)
    if not isinstance(network, torch.nn.Module) or not hasattr(tracker, "episode_input"):
        raise ConfigError(f"tracker {tracker.name!r} has no neural network to export (only learned trackers do)")
    tracker_id = tracker_id or tracker.name
    feats = example_features(tracker)
    with torch.no_grad():
        x = tracker.episode_input(feats).to("cpu", torch.float32)
    network = network.to("cpu").eval()
    dynamic = {"input": {0: "batch", 2: "frames"}, "directions": {0: "batch", 1: "frames"}}
    with atomic_path(out, suffix=".onnx") as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            torch.onnx.export(network, (x,), str(tmp), input_names=["input"], output_names=["directions"],
                              dynamic_axes=dynamic, dynamo=False)
        except DoabenchError:
            raise
        except Exception as exc:
            raise ConfigError(f"ONNX export of {tracker_id!r} failed: {type(exc).__name__}: "
                              f"{str(exc).strip().splitlines()[0] if str(exc).strip() else ''}") from None
        try:
            import onnx

            model = onnx.load(str(tmp))
            for key, value in metadata(tracker, tracker_id).items():
                entry = model.metadata_props.add()
                entry.key, entry.value = key, value
            onnx.save(model, str(tmp))
        except ImportError:
            pass
    diff = None
    if verify:
        try:
            import onnxruntime as ort
        except ImportError:
            ort = None
        if ort is not None:
            session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
            longer = torch.cat([x, x], dim=2)  # another frame count: the frame axis is dynamic
            diff = 0.0
            for probe in (x, longer):
                with torch.no_grad():
                    ref = network(probe).numpy()
                got = session.run(None, {"input": probe.numpy()})[0]
                diff = max(diff, float(np.abs(got - ref).max()))
            if not diff <= 1e-3:
                raise ConfigError(f"ONNX export of {tracker_id!r} disagrees with torch (max |difference| {diff:.3g})")
    return {"path": Path(out), "input_shape": tuple(x.shape), "max_abs_diff": diff}
