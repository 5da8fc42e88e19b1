"""The ``locata`` task kind: an episode source over the recordings of one LOCATA task.

Spec parameters (``[locata]`` section of the task's TOML): ``task`` (1..6), ``array``
(``benchmark2``, ``dicit``, ``dummy``, ``eigenmike``), ``split`` (``dev`` default), ``vad``
(``webrtc`` default, the paper's: WebRTC VAD of the array audio; ``corpus``: the corpus VAD files;
``auto``: corpus files when present, else WebRTC on the source signal). Run-time options: ``locata_root`` (else ``$DOABENCH_LOCATA``), ``split`` (overrides the
spec's), ``vad``, ``source`` (a source name, for recordings with several).

Beyond the frame metrics every task has, the runner asks the source for its own scores of each
episode (:meth:`LocataEpisodes.extra_scores`: the challenge's measures on the required stamps,
doabench.locata.run_scores) and stores their summary under the results' ``locata`` key.

Registered through the ``doabench.task_kinds`` entry-point group (pyproject.toml), like every kind.
One episode per recording found, in recording order; the spec's ``episodes`` is only a
placeholder (the corpus copy decides).
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from doabench.envs.options import LocataOptions
from doabench.envs.spec import TaskSpec
from doabench.episode import Episode
from doabench.errors import ConfigError, NotFoundError
from doabench.locata.layout import find_recordings
from doabench.framing import FrameSpec
from doabench.locata.reader import VAD_MODES, read_recording
from doabench.locata.run_scores import episode_scores, summarise

LICENSE = "LOCATA corpus, ODC-BY 1.0, DOI 10.5281/zenodo.3630471"


class LocataEpisodes:
    """Episodes of a ``locata`` task: ``len()`` = recordings found, ``episode(i)`` reads the i-th.

    Scoring policy (the paper's Table II): the headline is the mean of the per-recording RMSAEs."""

    Options = LocataOptions
    headline = "recording_mean"

    def __init__(self, spec: TaskSpec, **options: str | None) -> None:
        opts = LocataOptions(**options)
        locata_root, split, vad, source = opts.locata_root, opts.split, opts.vad, opts.source
        params = dict(spec.params.get("locata", {}))
        if "task" not in params:
            raise ConfigError(f"task spec {spec.source_file or spec.id}: a locata task needs [locata] task = N")
        self.spec = spec
        self.task = int(params["task"])
        self.array = str(params.get("array", "benchmark2"))
        self.split = str(split or params.get("split", "dev"))
        self.vad = str(vad or params.get("vad", "webrtc"))
        if self.vad not in VAD_MODES:
            raise ConfigError(f"LOCATA vad option {self.vad!r} is not one of {', '.join(VAD_MODES)}")
        self.source = source
        self.fs = spec.frames.fs
        self.recordings = find_recordings(locata_root, self.split, self.task, self.array)
        self.root = self.recordings[0].root

    def __len__(self) -> int:
        return len(self.recordings)

    def episode(self, index: int) -> Episode:
        if not 0 <= index < len(self):
            raise NotFoundError(f"task {self.spec.id!r} has {len(self)} recordings in {self.root}/{self.split}; "
                                f"episode {index} does not exist")
        episode = read_recording(self.recordings[index], fs=self.fs, vad=self.vad, source=self.source)
        episode.metadata.update({"task": self.spec.id, "episode_index": index})
        return episode

    extra_key = "locata"

    def extra_scores(self, index: int, metadata: Mapping[str, Any], centres: np.ndarray, directions: np.ndarray,
                     frame_spec: FrameSpec) -> dict[str, Any] | None:
        """The challenge's measures and SRP-DNN's protocol of episode ``index``'s estimates on its
        recording's required stamps (doabench.locata.run_scores); ``centres`` ``(F,)`` its frame
        centres, ``directions`` ``(F, 3)`` the tracker's; None when its stamps cannot be scored."""
        return episode_scores(self.recordings[index], float(metadata["start_s"]), centres, directions,
                              frame_spec.window, frame_spec.fs)

    def summarise_extra(self, scores: list[dict[str, Any]]) -> dict[str, Any]:
        """The results' ``locata`` block from the episodes' :meth:`extra_scores`."""
        return summarise(scores)

    def vad_sources(self) -> dict[int, str]:
        """Per recording number, the VAD that is (or will be) used: ``webrtcvad-array``, ``corpus``
        or ``webrtcvad`` (of the source signal)."""
        out = {}
        for rec in self.recordings:
            names = rec.source_names()
            has_file = bool(names) and all(rec.vad_file(n).is_file() for n in names)
            if self.vad == "webrtc":
                out[rec.number] = "webrtcvad-array"
            else:
                out[rec.number] = "corpus" if has_file else "webrtcvad"
        return out

    def describe(self) -> dict[str, Any]:
        return {
            "corpus": LICENSE,
            "root": str(self.root),
            "split": self.split,
            "locata_task": self.task,
            "array": self.array,
            "recordings": [r.number for r in self.recordings],
            "vad": self.vad,
            "source": self.source,
            "vad_rule": self.vad,
            "vad_sources": {str(k): v for k, v in self.vad_sources().items()},
            "fs": self.fs,
            "truth": "v = R^T (s - p) per sample from interpolated poses; invalid required times are silent",
        }
