"""The Gymnasium environment every task runs in.

One episode is one recording (simulated trajectory or real recording). ``reset`` renders it and
returns the features of frame 0; each ``step(action)`` takes the tracker's direction for the
current frame, returns ``reward = -angular error`` (radians) for it and the features of the next
frame. The truth of a frame is only revealed in ``info`` after its step, so a tracker cannot peek.
An action of three NaNs (``doabench.NO_SOURCE``) says "no source" for the frame: it is scored at
the fixed error ``NO_SOURCE_ERROR_DEG`` (90 degrees) and ``info["no_source"]`` is True.
Nothing else about the episode is handed out while it runs: ``reset``'s ``info`` holds the episode
index, its frame count and frame times, never the scene (room, trajectory, array position, T60,
SNR, seed, speech). The evaluator's view of the episode (:meth:`DoaEnv.episode_metadata`,
:meth:`DoaEnv.episode_truth`, :attr:`DoaEnv.current_episode`) answers only once the episode is
over: after the step that terminates it, or after :meth:`DoaEnv.score_offline`.

Features are causal per frame (each needs only the samples of its own window), so computing all of
an episode's frames at reset is identical to streaming them (``doabench.features`` tests this);
the environment still hands them out one frame per step.

Non-causal trackers use the separate offline path :meth:`DoaEnv.offline_episode` and
:meth:`DoaEnv.score_offline`; results record ``causal: false``.
"""
from __future__ import annotations

import copy
import dataclasses
from collections import OrderedDict
from typing import Any, Sequence

import gymnasium
import numpy as np
from gymnasium import spaces
from numpy.typing import ArrayLike

from doabench.arrays import MicArray, get_array
from doabench.envs.registry import get_task_spec
from doabench.envs.sources import make_episode_source
from doabench.envs.spec import TaskSpec
from doabench.episode import Episode
from doabench.errors import ConfigError, InputError
from doabench.features.kinds import feature_kind
from doabench.features.spec import ObservationSpec
from doabench.framing import FrameSpec
from doabench.geometry import NO_SOURCE_ERROR_DEG, fold_to_upper, great_circle_error, is_no_source


class DoaEnv(gymnasium.Env):
    """``DoaEnv(task, observations)``, or ``gymnasium.make("doabench/<task>-v<version>",
    features=("srp", "srp_max"), resolution=(16, 32))``.

    Parameters: ``task`` (id or TaskSpec); ``observations``: what it observes, one
    :class:`~doabench.features.spec.ObservationSpec` (a tracker's
    :attr:`~doabench.Tracker.observation_spec`), kept whole as :attr:`observations`. Without it,
    the flat keywords describe them and are turned into that value once, here
    (:meth:`ObservationSpec.of <doabench.features.spec.ObservationSpec.of>`): ``features`` (srp,
    srp_max, gcc, spectrogram, audio or a registered plug-in kind; default srp and srp_max),
    ``resolution`` ((n_theta, n_phi) or "16x32"), ``delays`` ("nearest" or "exact"), ``frame_spec``
    (default: the task's) and ``spectrogram_frame_spec``. The environment frames every observation
    alike, so a kind on frames of its own other than the main ones is refused.
    ``device`` for simulation and features; ``episodes``:
    this environment's share of the task's episodes (indices), served in order by ``reset()``
    without an ``episode`` option, each once per pass (``info["repeat"]`` counts the passes; see
    :func:`doabench.envs.vector.make_vec`, which splits a task across sub-environments);
    ``librispeech``, ``locata_root``, ``split``, ``backend`` and other options go to the task's
    episode source.
    """

    metadata = {"render_modes": []}
    observation_space: spaces.Dict  # the plan's: {kind: Box} plus vad

    def __init__(self, task: str | TaskSpec, observations: ObservationSpec | None = None, *,
                 features: Sequence[str] | None = None, resolution: tuple[int, int] | str | None = None,
                 delays: str | None = None, frame_spec: FrameSpec | None = None, device: str | None = None,
                 cache_size: int = 2, episodes: Sequence[int] | None = None,
                 spectrogram_frame_spec: FrameSpec | None = None, **source_options: Any) -> None:
        super().__init__()
        self.spec_task = get_task_spec(task)
        flat = {"features": features, "resolution": resolution, "delays": delays, "frame_spec": frame_spec,
                "spectrogram_frame_spec": spectrogram_frame_spec}
        if observations is None:
            observations = ObservationSpec.of(("srp", "srp_max") if features is None else features, resolution,
                                              frame_spec or self.spec_task.frames, delays, spectrogram_frame_spec)
        elif not isinstance(observations, ObservationSpec):
            raise ConfigError(f"observations must be an ObservationSpec, got {type(observations).__name__}")
        elif any(v is not None for v in flat.values()):
            raise ConfigError(f"give the observations as one ObservationSpec or as keywords, not both "
                              f"({', '.join(k for k, v in flat.items() if v is not None)})")
        if observations.frames.fs != self.spec_task.frames.fs:
            raise ConfigError(f"task {self.spec_task.id!r} runs at {self.spec_task.frames.fs} Hz, "
                              f"not {observations.frames.fs} Hz")
        if observations.separate_spectrogram_grid:
            own = [str(k) for k in observations.kinds if feature_kind(k.kind).own_frames]
            raise ConfigError(f"the environment frames every observation on one grid "
                              f"({observations.frames.to_dict()}); {', '.join(own)} on frames of its own has another "
                              "number of frames: compute it with an ObservationPlan instead")
        #: what this environment observes, as the one value trackers declare and files store
        self.observations = observations
        self.device = device
        self.array: MicArray = get_array(self.spec_task.array)
        self.source = make_episode_source(self.spec_task, device=device, **source_options)
        self._cache: OrderedDict[int, tuple[Episode, dict[str, np.ndarray], dict[str, np.ndarray]]] = OrderedDict()
        self._cache_size = max(1, cache_size)
        # the one pipeline from an episode's audio to its observations, spaces included
        self.plan = self.observations.plan(self.array)
        self.observation_space = self.plan.observation_space()
        self.action_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
        self._t = 0
        self._episode_index: int | None = None
        self.episode_share: list[int] | None = None if episodes is None else self._check_share(episodes)
        self._share_next = 0  # position in the share of the next reset() without an episode option
        self._share_pass = 0  # completed passes through the share

    # -- what it observes (views of ``observations``) -----------------------------------------------
    @property
    def features(self) -> tuple[str, ...]:
        """The observation kinds' names (the observation keys besides ``vad``)."""
        return self.observations.kind_names

    @property
    def resolution(self) -> tuple[int, int] | None:
        """The SRP grid of the kinds on it, or None when it observes no map."""
        return self.observations.resolution

    @property
    def frame_spec(self) -> FrameSpec:
        """The frames of every observation."""
        return self.observations.frames

    def _check_share(self, episodes: Sequence[int]) -> list[int]:
        try:
            share = [int(i) for i in episodes]
        except (TypeError, ValueError):
            raise InputError(f"episodes must be a list of episode indices, got {episodes!r}") from None
        if not share:
            raise InputError("episodes is empty: give this environment at least one episode")
        bad = [i for i in share if not 0 <= i < self.n_episodes]
        if bad:
            raise InputError(f"task {self.spec_task.id!r} has episodes 0-{self.n_episodes - 1}; "
                             f"episodes {bad[:5]} do not exist")
        if len(set(share)) != len(share):
            raise InputError(f"episodes lists an episode twice: {share}")
        return share

    # -- episodes ---------------------------------------------------------------------------------
    @property
    def n_episodes(self) -> int:
        return len(self.source)

    def load_episode(self, index: int) -> tuple[Episode, dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Render episode ``index``; returns (episode, features (T, ...), truth (T, ...))."""
        if index in self._cache:
            self._cache.move_to_end(index)
            return self._cache[index]
        # Sources of precomputed features (dataset replay, doabench.datasets.replay) may serve them
        # directly: stored_features(index, observations) -> (episode, features incl. vad, truth), or
        # None to render.
        provider = getattr(self.source, "stored_features", None)
        stored = provider(index, self.observations) if provider else None
        if stored is not None:
            episode, feats, truth = stored
        else:
            episode = self.source.episode(index)
            array = episode.array or self.array
            if episode.n_mics != array.n_mics:
                raise InputError(f"episode {index} of {self.spec_task.id!r} has {episode.n_mics} channels but "
                                 f"array {array.name!r} has {array.n_mics} microphones")
            feats = self.plan.observations(episode.audio, episode.feature_vad, array, self.device)
            truth = episode.frame_truth(self.frame_spec)
        n = len(truth["directions"])
        feats["vad"] = feats["vad"].astype(np.int64) if "vad" in feats else truth["vad"].astype(np.int64)
        for k, v in feats.items():
            if len(v) != n:
                raise RuntimeError(f"feature {k!r} has {len(v)} frames, truth has {n}")  # a doabench bug
        entry = (episode, feats, truth)
        self._cache[index] = entry
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return entry

    def _observation(self, t: int) -> dict[str, Any]:
        if t >= self._n_frames:
            return {k: np.zeros(s.shape, s.dtype) if isinstance(s, spaces.Box) else 0
                    for k, s in self.observation_space.spaces.items()}
        obs = {k: self._feats[k][t].copy() for k in self.features}  # users may keep or modify it
        obs["vad"] = int(self._feats["vad"][t])
        return obs

    # -- gymnasium API ----------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        super().reset(seed=seed)
        options = options or {}
        repeat = None
        if "episode" in options:
            index = int(options["episode"])
        elif self.episode_share is not None:
            if seed is not None:  # a seeded reset starts the share afresh, as it restarts the RNG
                self._share_next, self._share_pass = 0, 0
            index, repeat = self.episode_share[self._share_next], self._share_pass
            self._share_next += 1
            if self._share_next == len(self.episode_share):
                # Vector envs auto-reset a finished sub-environment while the others still run:
                # it starts its share again, and info["repeat"] says these episodes came before.
                self._share_next, self._share_pass = 0, self._share_pass + 1
        else:
            index = int(self.np_random.integers(self.n_episodes))
        self._episode, self._feats, self._truth = self.load_episode(index)
        self._episode_index = index
        self._n_frames = len(self._truth["directions"])
        self._t = 0
        # What a deployed tracker could know too: no scene, truth or seed (episode_metadata() has them)
        info = {"episode": index, "n_frames": self._n_frames, "frame_times": self._truth["times"].copy()}
        if repeat is not None:
            info["repeat"] = repeat
        return self._observation(0), info

    def step(self, action: ArrayLike) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        if self._episode_index is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        if self._t >= self._n_frames:
            raise gymnasium.error.ResetNeeded("the episode is over; call reset()")
        a = np.asarray(action, dtype=np.float64)
        none = a.shape == (3,) and bool(is_no_source(a))
        if a.shape != (3,) or not (none or (np.all(np.isfinite(a)) and np.any(a))):
            raise InputError(f"action must be a finite, non-zero direction vector of shape (3,) or three NaNs "
                             f"(doabench.NO_SOURCE: no source), got {a.shape} {a!r}")
        truth = self._truth["directions"][self._t]
        error = self._scored_errors(a, truth)
        info = {"frame": self._t, "truth": truth.copy(), "vad": bool(self._truth["vad"][self._t]),
                "error_rad": error, "time_s": float(self._truth["times"][self._t]), "no_source": none}
        self._t += 1
        terminated = self._t >= self._n_frames
        return self._observation(self._t), -error, terminated, False, info

    # -- offline path for non-causal trackers ------------------------------------------------------
    def offline_episode(self) -> dict[str, np.ndarray]:
        """All frames of the current episode at once (``(T, ...)`` per key, plus ``vad``).

        Only for non-causal trackers; results made this way record ``causal: false``.
        """
        if self._episode_index is None:
            raise gymnasium.error.ResetNeeded("call reset() before offline_episode()")
        return {**{k: self._feats[k] for k in self.features}, "vad": self._feats["vad"]}

    def score_offline(self, directions: Any) -> np.ndarray:
        """Score every frame of the current episode at once: ``directions`` ``(T, 3)`` (the offline
        tracker's output; a row of three NaNs says no source) -> the per-frame errors ``(T,)`` in
        radians. Ends the episode, as the last ``step`` does: later steps raise ``ResetNeeded``."""
        if self._episode_index is None:
            raise gymnasium.error.ResetNeeded("call reset() before score_offline()")
        if self._t >= self._n_frames and self._n_frames:
            raise gymnasium.error.ResetNeeded("the episode is over; call reset()")
        a = np.asarray(directions, dtype=np.float64)
        if a.shape != (self._n_frames, 3) or not np.all(is_no_source(a) | (np.all(np.isfinite(a), axis=1)
                                                                          & np.any(a, axis=1))):
            raise InputError(f"directions must be finite, non-zero vectors (or rows of three NaNs: no source) of "
                             f"shape ({self._n_frames}, 3), got {a.shape}")
        errors = np.asarray(self._scored_errors(a, self._truth["directions"]), dtype=np.float64).reshape(-1)
        self._t = self._n_frames
        return errors

    def _scored_errors(self, estimate: np.ndarray, truth: np.ndarray) -> Any:
        """Great-circle errors in radians of estimates ``(..., 3)`` against the truth as scored
        (:meth:`_as_scored`); a frame without an estimate (three NaNs) counts ``NO_SOURCE_ERROR_DEG``."""
        error = np.where(is_no_source(estimate), np.radians(NO_SOURCE_ERROR_DEG),
                         great_circle_error(*self._as_scored(estimate, truth)))
        return float(error) if error.ndim == 0 else error

    def _as_scored(self, estimate: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Estimate and truth as every score sees them (doabench.metrics.score_frames): mirror-folded
        onto the upper half-space for a planar array, which cannot tell a direction from its mirror."""
        array = self._episode.array or self.array
        return (fold_to_upper(estimate), fold_to_upper(truth)) if array.planar else (estimate, truth)

    # -- what the tracker may use besides the observations -----------------------------------------
    @property
    def episode_array(self) -> MicArray:
        """The array the current episode was recorded with: the task's, or the recording's own
        (LOCATA's measured positions). Geometry of the microphones in the array frame only: a
        recording's own array is handed out without the file it was read from (its folder holds
        the recording's truth)."""
        if self._episode_index is None:
            raise gymnasium.error.ResetNeeded("call reset() before episode_array")
        own = self._episode.array
        if own is None:
            return self.array
        return dataclasses.replace(own, source=f"episode {self._episode_index} of {self.spec_task.id}")

    # -- the evaluator's view: only once the episode is over ---------------------------------------
    @property
    def episode_over(self) -> bool:
        """True once every frame of the current episode has been scored (by ``step`` or
        :meth:`score_offline`)."""
        return self._episode_index is not None and self._t >= self._n_frames

    def _require_over(self, what: str) -> None:
        if self._episode_index is None:
            raise gymnasium.error.ResetNeeded(f"call reset() before {what}")
        if self._t < self._n_frames:
            raise RuntimeError(f"{what} of episode {self._episode_index} is available once the episode is over "
                               f"(frame {self._t} of {self._n_frames} is next): step to termination, or call "
                               "score_offline()")

    @property
    def current_episode(self) -> Episode:
        """The :class:`~doabench.episode.Episode` that the last ``reset()`` loaded (audio, array,
        truth, metadata); once the episode is over."""
        self._require_over("current_episode")
        return self._episode

    def episode_truth(self) -> dict[str, np.ndarray]:
        """Per-frame truth of the current episode (``directions``, ``vad``, ``times``, ...); once the
        episode is over (the runner reads it after the tracker has finished)."""
        self._require_over("episode_truth()")
        return self._truth

    def episode_metadata(self) -> dict[str, Any]:
        """A copy of the current episode's metadata (scene parameters, room, trajectory, seeds,
        speech, recording ids): what the results record per episode; once the episode is over."""
        self._require_over("episode_metadata()")
        return copy.deepcopy(self._episode.metadata)
