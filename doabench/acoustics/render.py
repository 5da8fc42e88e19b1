"""Render a :class:`~doabench.acoustics.scenes.Scene` into an :class:`~doabench.episode.Episode`.

Steps (the paper's Fig. 3, plus an optional directional noise):

1. the speech chunk recorded in the scene is re-created by the speech source (mean removed, VAD,
   silent samples zeroed);
2. the simulator convolves it with the RIRs of the trajectory points (overlap-add over equal
   segments, see :mod:`doabench.acoustics.trajectories`); a static source uses one RIR;
3. the reference signal power is the power of the **direct path** averaged over the microphones
   and over the **non-silent frames**: frames of ``K = 4096`` samples with hop ``3K/4``
   (doabench.framing) whose samples are more than 2/3 voice-active. The mean is the mean of the
   frames' powers, as the paper computes it. The direct path is a pure delay with gain
   ``1 / (4 pi r)``, so its power is computed analytically (:func:`direct_path_power`: the speech
   power per sample weighted by the segment's mean squared gain, shifted by the mean direct
   delay) instead of convolving the signal a second time (0.07 s per 20 s trajectory, a sixth of
   the simulation); it agrees with the convolved direct path
   (:func:`~doabench.acoustics.backends.base.direct_path`) within 0.1 dB (tested). Fallbacks: with
   no non-silent frame (very short or silent chunks) the voice-active samples, and with none of
   those all samples;
4. spatially white Gaussian noise of power ``P / 10^(SNR/10)`` is added to every microphone
   (the "noise" stream of the scene seed);
5. optionally (beyond the paper) a stationary directional noise (pink, brown or low-passed white
   noise) is simulated from its static position and added. Its SNR is measured **at the
   microphones**: the reverberant speech power over the non-silent frames versus the reverberant
   noise power over all samples. (A far noise source is dominated by reverberation, more so for
   low-frequency noise, so its direct path says little about how loud it is in the recording.)

Same scene, same backend and same device give bitwise identical audio: every random draw comes
from a named stream of the scene seed (the builtin simulator's diffuse tail included).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from doabench.acoustics.scenes import Scene, scene_streams
from doabench.arrays import MicArray, get_array
from doabench.episode import Episode
from doabench.errors import ConfigError
from doabench.framing import DEFAULT_WINDOW, frame_signal, frame_vad

SNR_WINDOW = DEFAULT_WINDOW
SNR_HOP = 3 * DEFAULT_WINDOW // 4


@dataclass
class RenderedScene:
    """Every component of a rendered scene, ``(M, L)`` float32 unless said otherwise.

    ``episode.audio = reverberant + noise (+ directional)``; ``speech`` ``(L,)`` float64;
    ``direct`` the convolved direct path (for inspection; None unless asked for);
    ``signal_power`` is the reference (direct-path, non-silent frames) power and ``active_frames``
    ``(T,)`` bool the frames it was measured over (None when a fallback was used, see the module
    docstring).
    """

    episode: Episode
    speech: np.ndarray
    reverberant: np.ndarray
    direct: np.ndarray | None
    noise: np.ndarray
    directional: np.ndarray | None
    signal_power: float
    noise_power: float
    active_frames: np.ndarray | None


def _power_over_active_frames(power: np.ndarray, vad: np.ndarray) -> tuple[float, np.ndarray | None]:
    """Mean of the per-sample ``power`` ``(L,)`` (already averaged over microphones) over the
    non-silent frames of ``vad`` ``(L,)``, with the module docstring's fallbacks."""
    frames_vad = np.asarray(frame_vad(vad, SNR_WINDOW, SNR_HOP), dtype=bool)
    if frames_vad.any():
        frames = frame_signal(power, SNR_WINDOW, SNR_HOP)  # (T, K) strided view
        return float(frames[frames_vad].mean()), frames_vad
    active = np.asarray(vad, dtype=bool)
    if active.any():
        return float(np.mean(power[active])), None
    return float(np.mean(power)), None


def reference_power(signals: np.ndarray, vad: np.ndarray) -> tuple[float, np.ndarray | None]:
    """Mean power of ``signals`` ``(M, L)`` over the non-silent frames of ``vad`` ``(L,)``.

    Returns ``(power, active frames (T,) bool or None when a fallback was used)``.
    """
    x = np.asarray(signals, dtype=np.float64)
    return _power_over_active_frames(np.einsum("ml,ml->l", x, x) / x.shape[0], vad)


def direct_path_power(sources: np.ndarray, mics: np.ndarray, speech: np.ndarray, vad: np.ndarray,
                      fs: int) -> tuple[float, np.ndarray | None]:
    """:func:`reference_power` of the direct path, analytically (see the module docstring).

    ``sources`` ``(S, 3)`` trajectory points, ``mics`` ``(M, 3)`` or ``(S, M, 3)`` for a moving
    array (room coordinates), ``speech``
    ``(L,)``: sample ``n`` of segment ``i`` reaches microphone ``m`` with gain ``1 / (4 pi r_im)``
    after ``r_im / c``; its power averaged over microphones is ``mean_m g_im**2 * speech[n]**2``,
    placed at ``n`` plus the mean direct delay.
    """
    from doabench.acoustics.trajectories import segment_of_samples
    from doabench.geometry import SPEED_OF_SOUND

    mics = np.asarray(mics, np.float64)
    dist = np.linalg.norm(np.asarray(sources, np.float64)[:, None] - (mics if mics.ndim == 3 else mics[None]), axis=-1)
    gain_sq = np.mean((1.0 / (4.0 * np.pi * dist)) ** 2, axis=1)  # (S,)
    n = len(speech)
    power = gain_sq[segment_of_samples(n, len(gain_sq))] * np.square(np.asarray(speech, np.float64))
    delay = min(int(round(float(dist.mean()) / SPEED_OF_SOUND * fs)), n)
    shifted = np.zeros(n)
    shifted[delay:] = power[: n - delay]
    return _power_over_active_frames(shifted, vad)


def _seed_of(stream: np.random.SeedSequence) -> int:
    """A 63-bit integer seed for backends that take one (torch generators, gpuRIR)."""
    return int(stream.generate_state(1, np.uint64)[0] >> np.uint64(1))


def _simulate(sim, room, sources: np.ndarray, mics: np.ndarray, signal: np.ndarray, fs: int,
              seed: int) -> np.ndarray:
    out = sim.simulate(room, sources, mics, signal, fs, seed=seed)
    return np.asarray(out.detach().cpu().numpy() if hasattr(out, "detach") else out, dtype=np.float32)


def noise_signal(kind: str, n_samples: int, fs: int, rng: np.random.Generator) -> np.ndarray:
    """Stationary noise ``(L,)`` float64 with unit power: ``pink`` (1/f power), ``brown``
    (1/f^2) or ``lowpass`` (white through a 4th-order Butterworth at 500 Hz, fan-like hum)."""
    white = rng.standard_normal(n_samples)
    if kind == "lowpass":
        from scipy.signal import butter, sosfilt

        x = sosfilt(butter(4, 500.0, fs=fs, output="sos"), white)
    elif kind in ("pink", "brown"):
        spec = np.fft.rfft(white)
        f = np.fft.rfftfreq(n_samples, 1.0 / fs)
        # Below 20 Hz the 1/f shape is flattened so the noise does not drift like a random walk.
        shape = np.maximum(f, 20.0) ** (-0.5 if kind == "pink" else -1.0)
        shape[0] = 0.0
        x = np.fft.irfft(spec * shape, n_samples)
    else:
        raise ConfigError(f"unknown directional noise kind {kind!r} (pink, brown, lowpass)")
    return x / np.sqrt(np.mean(x**2) + 1e-300)


def _resolve(simulator, device):
    if isinstance(simulator, str):
        from doabench.acoustics.simulators import get_simulator

        return get_simulator(simulator, device=device)
    if not hasattr(simulator, "simulate"):
        raise ConfigError(f"simulator must be a backend name or a Simulator, got {type(simulator).__name__}")
    return simulator


def render_components(scene: Scene, speech_source, array: MicArray | str | None = None,
                      simulator: Any = "builtin", device: str | None = None,
                      keep_direct: bool = False) -> RenderedScene:
    """Render ``scene`` and keep every component (see :func:`render_scene` for the arguments);
    ``keep_direct`` also convolves the direct path (for inspection and tests)."""
    from doabench.acoustics.backends.base import direct_path

    if scene.speech is None:
        raise ConfigError("this scene was drawn without a speech source and cannot be rendered")
    if array is not None:
        array = get_array(array)
        if array.positions.shape != scene.mic_positions.shape or not np.allclose(array.positions, scene.mic_positions):
            # Rendering a scene with another array: record the array actually used (and check it fits).
            scene = replace(scene, array_name=array.name, mic_positions=np.array(array.positions))
    sim = _resolve(simulator, device)
    streams = scene_streams(scene.seed)
    fs, n = scene.fs, scene.n_samples

    chunk = speech_source.load(scene.speech)
    if chunk.signal.shape != (n,):
        raise ConfigError(f"speech chunk has {chunk.signal.shape[0]} samples, the scene needs {n}")
    speech = chunk.signal.astype(np.float64)
    mics = np.array(scene.mic_room_positions)  # writable copies: torch refuses read-only arrays
    sources = np.array(scene.source_positions)
    # The SNR reference is the talker's level before any pause, so pauses change no noise level.
    signal_power, active_frames = direct_path_power(sources, mics, speech, chunk.vad, fs)
    if not signal_power > 0:
        raise ConfigError("the scene's speech chunk is silent: cannot set an SNR")
    vad = np.asarray(chunk.vad, dtype=bool)
    if scene.speech_pauses:  # the talker is silent there (beyond the paper, see SceneDistribution)
        vad = vad.copy()
        for start, stop in scene.speech_pauses:
            speech[start:stop] = 0.0
            vad[start:stop] = False

    reverberant = _simulate(sim, scene.room, sources, mics, speech, fs, _seed_of(streams["simulator"]))
    direct = None
    if keep_direct:
        direct = direct_path(scene.room, sources, mics, speech, fs, device=getattr(sim, "device", None))

    noise_power = signal_power / 10.0 ** (scene.snr_db / 10.0)
    # float32 throughout (the audio is float32 anyway), drawn by torch: numpy's generator took
    # 60 ms for the 12 x 320000 samples of a 20 s trajectory, a sixth of the whole simulation.
    gen = torch.Generator().manual_seed(_seed_of(streams["noise"]))
    noise = torch.randn(reverberant.shape, generator=gen, dtype=torch.float32).numpy()
    noise *= np.float32(np.sqrt(noise_power))
    audio = reverberant + noise

    directional = None
    if scene.directional_noise is not None:
        dn = scene.directional_noise
        sig = noise_signal(dn.kind, n, fs, np.random.default_rng(streams["directional_signal"]))
        pos = np.array(dn.position[None])
        directional = _simulate(sim, scene.room, pos, mics, sig, fs, _seed_of(streams["directional"]))
        speech_at_mics, _ = reference_power(reverberant, vad)
        directional *= np.float32(np.sqrt(speech_at_mics / 10.0 ** (dn.snr_db / 10.0)
                                          / max(float(np.mean(np.square(directional, dtype=np.float64))), 1e-300)))
        audio = audio + directional

    metadata = {
        "scene": scene.to_dict(),
        "backend": sim.name,
        "backend_versions": dict(sim.versions()),
        "device": None if device is None else str(device),
        "signal_power": signal_power,
        "noise_power": noise_power,
        "snr_reference": f"direct-path power over non-silent frames (K={SNR_WINDOW}, hop={SNR_HOP}, >2/3 VAD)",
    }
    episode = Episode(
        audio=audio.astype(np.float32, copy=False),
        fs=fs,
        sample_vad=vad,
        sample_directions=scene.sample_directions(n),
        metadata=metadata,
    )
    return RenderedScene(episode, speech, reverberant, direct, noise, directional, signal_power, noise_power,
                         active_frames)


def render_scene(scene: Scene, speech_source, array: MicArray | str | None = None,
                 simulator: Any = "builtin", device: str | None = None) -> Episode:
    """Simulate ``scene`` and return its :class:`Episode` (audio ``(M, L)`` float32 and truth).

    ``speech_source``: the source that drew ``scene.speech`` (e.g. the same LibriSpeechSource);
    ``array``: the array to simulate (None: the scene's recorded microphone positions; another
    array is recorded in the metadata's scene); ``simulator``: a backend name ("builtin",
    "pyroomacoustics", "gpurir") or a Simulator; ``device`` goes to :func:`get_simulator`.
    Metadata: ``scene`` (dict), ``backend``, ``backend_versions``, ``device``, ``signal_power``,
    ``noise_power``, ``snr_reference``.
    """
    return render_components(scene, speech_source, array, simulator, device).episode
