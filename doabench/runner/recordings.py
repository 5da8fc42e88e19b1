"""Tracking a recording that is not a task episode (``doabench track``): features of the user's
audio through the :class:`~doabench.features.plan.ObservationPlan`, then the evaluation loop's
tracker calls and checks (:mod:`doabench.runner.loop`), in memory (:func:`track_recording`) or
chunk by chunk with memory bounded by the chunk size (:func:`track_stream`)."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Iterable, Iterator

import numpy as np

from doabench.arrays import MicArray
from doabench.features.kinds import feature_kind
from doabench.runner.loop import check_directions, guarded, step_frame, track_frames
from doabench.trackers.base import Tracker, observations_of

if TYPE_CHECKING:
    from doabench.recording import Recording, StreamingWebrtcVad

#: ``(audio (n_mics, n), sample_vad (n,) or None)``: one chunk of a recording, in order
Chunk = tuple[np.ndarray, np.ndarray | None]


def recording_vad(audio: np.ndarray, fs: int) -> np.ndarray:
    """Per-sample VAD ``(samples,)`` of a multichannel recording from the WebRTC VAD of its channel mean."""
    from doabench.corpora.vad import webrtc_vad

    mono = audio.mean(0)
    peak = float(np.max(np.abs(mono))) or 1.0
    return webrtc_vad(mono / peak, fs)[0]


def track_recording(tracker: Tracker, array: MicArray, audio: np.ndarray, sample_vad: np.ndarray | None,
                    delays: str | None = None, device: str | None = None) -> dict[str, np.ndarray]:
    """Features -> tracker -> ``{"times", "directions" (T, 3), "vad" (T,)}`` for one recording, on
    the tracker's own observations (``delays``: another delay mode on purpose)."""
    spec = tracker.frame_spec
    feats = observations_of(tracker).with_delays(delays).plan(array).observations(audio, sample_vad, device=device)
    n = len(feats["vad"])
    guarded(tracker, "reset()", lambda: tracker.reset(array, frame_spec=spec))

    def frame(t: int) -> dict[str, Any] | None:
        return {**{k: v[t] for k, v in feats.items()}, "vad": int(feats["vad"][t])} if t < n else None

    # the runner's loop: the same step/track calls and checks as `doabench run`
    directions = track_frames(tracker, n, frame(0), lambda t, _: frame(t + 1), lambda: feats)
    return {"times": spec.times(n), "directions": directions, "vad": feats["vad"].astype(bool)}


def track_stream(tracker: Tracker, array: MicArray, chunks: Iterable[Chunk], delays: str | None = None,
                 device: str | None = None) -> dict[str, np.ndarray]:
    """:func:`track_recording` on a recording given as chunks, in memory bounded by the chunk size.

    ``chunks``: iterable of ``(audio (n_mics, n), sample_vad (n,) | None)`` in order. Features
    come from the streaming extractor (equal to the offline one); a causal tracker steps through
    each chunk's frames as they complete, a non-causal one gets the whole feature sequence
    (frames x features, not samples) at the end. Same result as :func:`track_recording` on the
    concatenated chunks.
    """
    import torch

    from doabench.features.plan import framed_audio
    from doabench.features.streaming import FrameStream

    spec = tracker.frame_spec
    observations = observations_of(tracker)
    extractor = observations.with_delays(delays).plan(array).streaming_extractor()
    framed = [k for k in observations.kind_names if feature_kind(k).framed]  # the recording's samples, framed
    framer = FrameStream(spec) if framed else None
    guarded(tracker, "reset()", lambda: tracker.reset(array, frame_spec=spec))
    directions: list[np.ndarray] = []
    parts: dict[str, list[np.ndarray]] = {}
    vads: list[np.ndarray] = []
    t = 0
    with torch.inference_mode():
        for audio, sample_vad in chunks:
            x = torch.as_tensor(np.ascontiguousarray(audio), dtype=torch.float32, device=device)
            vad = None if sample_vad is None else torch.as_tensor(np.asarray(sample_vad, bool), device=device)
            feats = {k: v.detach().cpu().numpy() for k, v in extractor.push(x, vad).items()}
            if framer is not None:
                a = torch.from_numpy(np.ascontiguousarray(audio, dtype=np.float32))[None]
                seg = framer.push(a, torch.ones((1, a.shape[-1]), dtype=torch.bool))
                frames = (np.zeros((0, a.shape[1], spec.window), np.float32) if seg is None else
                          framed_audio(seg[0][0].numpy(), spec))
                feats.update({k: frames for k in framed})
            feats["vad"] = np.asarray(feats["vad"]).astype(np.int64)
            vads.append(feats["vad"])
            if tracker.causal:
                for i in range(len(feats["vad"])):
                    directions.append(step_frame(tracker, {**{k: v[i] for k, v in feats.items()},
                                                           "vad": int(feats["vad"][i])}, t))
                    t += 1
            else:
                for k, v in feats.items():
                    parts.setdefault(k, []).append(v)
    vad_all = np.concatenate(vads) if vads else np.zeros(0, np.int64)
    n = len(vad_all)
    if tracker.causal:
        out = np.stack(directions) if n else np.zeros((0, 3))
    else:
        feats = {k: np.concatenate(v) for k, v in parts.items()}
        out = check_directions(tracker, guarded(tracker, "track()", tracker.track, feats), n)
    return {"times": spec.times(n), "directions": out, "vad": vad_all.astype(bool)}


def recording_chunks(rec: Recording, vad: str, block: int | None = None,
                     sample_vad: np.ndarray | None = None) -> tuple[Iterator[Chunk], bool]:
    """``(chunks, silent)`` for :func:`track_stream` from a :class:`~doabench.recording.Recording`.

    The recording is read block by block (up to three times: silence and peak, the WebRTC VAD,
    the features), never held whole; the chunks equal ``(audio, sample VAD)`` as ``main``
    computed them offline (digital silence: no sample active whatever ``vad`` says).
    ``sample_vad`` ``(rec.samples,)``: a given per-sample VAD (``vad="truth"``, from a truth
    table's frames) used as it is, silence or not, as ``doabench run`` uses the scene's.
    """
    from doabench.recording import BLOCK_SAMPLES, StreamingWebrtcVad

    block = block or BLOCK_SAMPLES
    silent, peak = True, 0.0
    for x in rec.blocks(block):
        silent = silent and not np.any(x)
        if vad == "webrtc" and sample_vad is None:
            peak = max(peak, float(np.max(np.abs(x.mean(0)))))
    decisions: np.ndarray | None = None
    stream: StreamingWebrtcVad | None = None
    if not silent and vad == "webrtc" and sample_vad is None:
        stream = StreamingWebrtcVad(rec.fs, peak or 1.0)
        for x in rec.blocks(block):
            stream.push(x)
        decisions, _ = stream.finish()

    def chunks() -> Iterator[Chunk]:
        start = 0
        for x in rec.blocks(block):
            n = x.shape[-1]
            v: np.ndarray | None
            if sample_vad is not None:
                v = np.asarray(sample_vad[start:start + n], bool)
            elif silent:
                v = np.zeros(n, bool)
            else:
                v = None if stream is None or decisions is None else stream.sample_vad(decisions, start, n)
            start += n
            yield x, v

    return chunks(), silent
