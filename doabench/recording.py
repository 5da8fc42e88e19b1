"""Reading a user's multichannel recording, with every check a user needs a clear message for."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from doabench.arrays import MicArray
from doabench.errors import InputError, NotFoundError
from doabench.resampling import rational_factors, resample


def _existing_file(path: str | Path) -> Path:
    """``path`` as a Path; a missing path or a folder is a one-line error naming it."""
    path = Path(path)
    if not path.exists():
        raise NotFoundError(f"recording {path} does not exist")
    if not path.is_file():
        raise InputError(f"recording {path} is not a file")
    return path


def read_audio(path: str | Path) -> tuple[np.ndarray, int]:
    """``(n_channels, samples)`` float32 and the sample rate; unreadable files are InputErrors."""
    import soundfile as sf

    path = _existing_file(path)
    try:
        data, sr = sf.read(str(path), dtype="float32", always_2d=True)
    except Exception as exc:  # libsndfile reports every unreadable file its own way
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"cannot read {path} as audio ({msg})") from None
    return np.ascontiguousarray(data.T), int(sr)


def float_wav_bytes(audio: np.ndarray, fs: int) -> bytes:
    """``audio`` ``(n_channels, samples)`` as the bytes of a 32-bit float WAV that depend only on
    the samples and ``fs``.

    libsndfile adds a PEAK chunk to float WAVs holding the time of writing (seconds since 1970),
    so the same simulation written in two different seconds gave two different files; that
    timestamp (the chunk's second 32-bit field) is set to 0 here. The peaks stay: readers that use
    them still find them."""
    import io

    import soundfile as sf

    buf = io.BytesIO()
    sf.write(buf, np.asarray(audio, dtype=np.float32).T, int(fs), format="WAV", subtype="FLOAT")
    data = bytearray(buf.getvalue())
    at = 12  # the chunks after "RIFF", size, "WAVE": id, 32-bit size, data (padded to even)
    while at + 8 <= len(data) and data[at:at + 4] != b"data":
        size = int.from_bytes(data[at + 4:at + 8], "little")
        if data[at:at + 4] == b"PEAK":
            data[at + 12:at + 16] = bytes(4)  # the chunk's version, then the timestamp
            break
        at += 8 + size + (size & 1)
    return bytes(data)


def load_recording(path: str | Path, array: MicArray, fs: int, allow_resample: bool = False,
                   min_samples: int = 0) -> tuple[np.ndarray, bool]:
    """A recording checked against the array and the sample rate: ``((n_mics, samples), resampled)``.

    Errors: channel count not the array's, another sample rate (unless ``allow_resample``),
    non-finite samples, fewer than ``min_samples`` samples (e.g. one analysis window).
    """
    path = Path(path)
    audio, sr = read_audio(path)
    if audio.shape[0] != array.n_mics:
        raise InputError(f"{path} has {audio.shape[0]} channels but array {array.name!r} has "
                         f"{array.n_mics} microphones")
    if not np.all(np.isfinite(audio)):
        raise InputError(f"{path} contains NaN or infinite samples")
    resampled = False
    if sr != fs:
        if not allow_resample:
            raise InputError(f"{path} is sampled at {sr} Hz, not {fs} Hz: pass --resample to convert it")
        try:
            rational_factors(sr, fs)  # bounded before any filter
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None
        audio, resampled = resample(audio, sr, fs).astype(np.float32), True
    if audio.shape[-1] < min_samples:
        raise InputError(f"{path} has {audio.shape[-1]} samples at {fs} Hz, shorter than one "
                         f"{min_samples}-sample window")
    return audio, resampled


# -- streaming: long recordings read block by block, never whole ------------------------------

#: samples (at the analysis rate) per block read from a recording
BLOCK_SAMPLES = 1 << 17


def _resample_filter(up: int, down: int) -> np.ndarray:
    """The float32 anti-aliasing filter ``resample_poly`` designs (window ('kaiser', 5.0)) for float32 input."""
    from scipy.signal import firwin

    max_rate = max(up, down)
    return np.asarray(firwin(2 * 10 * max_rate + 1, 1.0 / max_rate, window=("kaiser", 5.0)), dtype=np.float32)


class Recording:
    """A checked recording on disk, read block by block at the analysis rate ``fs``.

    ``blocks()`` yields ``(n_channels, n)`` float32 blocks whose concatenation equals
    :func:`load_recording`'s array (bit for bit, resampling included: each resampled block is
    ``resample_poly`` of the input samples its outputs depend on, so every output sample is the
    same sum of the same products). At most one block of input is held at a time.
    """

    def __init__(self, path: Path, n_channels: int, sr: int, n_in: int, fs: int) -> None:
        self.path, self.n_channels, self.sr, self.fs, self.n_in = path, n_channels, sr, fs, n_in
        try:
            self.up, self.down = rational_factors(sr, fs)
        except InputError as exc:  # named after the file that claims the rate
            raise InputError(f"{path}: {exc}") from None
        self.resampled = sr != fs
        self.samples = -(-n_in * self.up // self.down)  # resample_poly's output length

    def _read(self, f, start: int, stop: int) -> np.ndarray:
        f.seek(start)
        data = f.read(stop - start, dtype="float32", always_2d=True)
        return np.ascontiguousarray(data.T)

    def raw_blocks(self, block: int = BLOCK_SAMPLES):
        """The file's own samples ``(n_channels, n)`` float32, block by block (no resampling)."""
        import soundfile as sf

        with sf.SoundFile(str(self.path)) as f:
            for start in range(0, self.n_in, block):
                x = self._read(f, start, min(self.n_in, start + block))
                if x.shape[-1] == 0:
                    break
                yield x

    def blocks(self, block: int = BLOCK_SAMPLES):
        """The recording at ``fs``, ``(n_channels, n)`` float32 blocks of ``block`` samples (the last shorter)."""
        if not self.resampled:
            yield from self.raw_blocks(block)
            return
        import soundfile as sf
        from scipy.signal import resample_poly

        up, down = self.up, self.down
        h = _resample_filter(up, down)
        half_len = (len(h) - 1) // 2
        n_pre_remove = (half_len + down - half_len % down) // down
        reach = -(-(len(h) + 2 * down) // up) + 2  # input samples an output depends on, with slack
        with sf.SoundFile(str(self.path)) as f:
            for m0 in range(0, self.samples, block):
                m1 = min(self.samples, m0 + block)
                # upfirdn output k = m + n_pre_remove sums inputs i with i * up in [k*down - len(h') + 1, k*down]
                lo = max(0, (m0 + n_pre_remove) * down // up - reach)
                lo -= lo % down  # a block starting at a multiple of `down` keeps the output phase
                hi = min(self.n_in, (m1 - 1 + n_pre_remove) * down // up + reach)
                y = resample_poly(self._read(f, lo, hi), up, down, axis=-1, window=h)
                off = lo * up // down
                yield np.ascontiguousarray(y[:, m0 - off:m1 - off], dtype=np.float32)


def open_recording(path: str | Path, array: MicArray, fs: int, allow_resample: bool = False,
                   min_samples: int = 0, check_finite: bool = True) -> Recording:
    """:func:`load_recording`'s checks, in its order, without holding the recording in memory.

    ``check_finite`` reads the file once (block by block) to refuse non-finite samples up front.
    """
    import soundfile as sf

    path = _existing_file(path)
    try:
        with sf.SoundFile(str(path)) as f:
            n_channels, sr, n_in = f.channels, int(f.samplerate), f.frames
            f.read(1, dtype="float32")  # a header that opens but data that does not decode
    except Exception as exc:  # libsndfile reports every unreadable file its own way
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"cannot read {path} as audio ({msg})") from None
    if n_channels != array.n_mics:
        raise InputError(f"{path} has {n_channels} channels but array {array.name!r} has "
                         f"{array.n_mics} microphones")
    if sr != fs and not allow_resample:
        rec = None
    else:
        rec = Recording(path, n_channels, sr, n_in, fs)  # its factors, bounded before any filter
    if check_finite:
        scan = Recording(path, n_channels, sr, n_in, sr)
        try:
            finite = all(np.all(np.isfinite(x)) for x in scan.raw_blocks())
        except Exception as exc:
            msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise InputError(f"cannot read {path} as audio ({msg})") from None
        if not finite:
            raise InputError(f"{path} contains NaN or infinite samples")
    if rec is None:
        raise InputError(f"{path} is sampled at {sr} Hz, not {fs} Hz: pass --resample to convert it")
    if rec.samples < min_samples:
        raise InputError(f"{path} has {rec.samples} samples at {fs} Hz, shorter than one "
                         f"{min_samples}-sample window")
    return rec


class StreamingWebrtcVad:
    """``doabench track``'s recording VAD (WebRTC VAD of the channel mean over its peak), chunk by chunk.

    Equals :func:`doabench.corpora.vad.webrtc_vad` on the whole signal: the same 10 ms int16
    frames go through one ``webrtcvad.Vad`` per mode in order (the VAD keeps state across
    frames), every mode at once, and the mode is chosen at :meth:`finish` by the same rule.
    Holds one bool per 10 ms frame and mode, not samples.
    """

    def __init__(self, fs: int, peak: float) -> None:
        import webrtcvad

        from doabench.corpora.vad import DEFAULT_MODES, FRAME_MS, MIN_ACTIVE, WEBRTC_RATES
        from doabench.errors import ConfigError

        if fs not in WEBRTC_RATES:
            raise ConfigError(f"WebRTC VAD supports sample rates {WEBRTC_RATES}, got {fs}")
        self.fs, self.peak, self.modes, self.min_active = fs, peak, DEFAULT_MODES, MIN_ACTIVE
        self.frame_len = fs * FRAME_MS // 1000
        self._vads = [webrtcvad.Vad(m) for m in self.modes]
        self._decisions: list[list[np.ndarray]] = [[] for _ in self.modes]
        self._rest = np.zeros(0, np.float32)
        self.length = 0

    def _classify(self, x: np.ndarray) -> None:
        n = x.shape[0] // self.frame_len
        pcm = np.clip(np.round(x.astype(np.float64) * 32767.0), -32768, 32767).astype("<i2")
        frames = pcm.reshape(n, self.frame_len)
        for vad, out in zip(self._vads, self._decisions):
            out.append(np.fromiter((vad.is_speech(f.tobytes(), self.fs) for f in frames), dtype=bool, count=n))

    def push(self, audio: np.ndarray) -> None:
        """Add a block ``(n_channels, n)`` of the recording."""
        mono = audio.mean(0) / self.peak
        self.length += mono.shape[0]
        x = np.concatenate([self._rest, mono]) if self._rest.size else mono
        whole = x.shape[0] // self.frame_len * self.frame_len
        if whole:
            self._classify(x[:whole])
        self._rest = x[whole:].copy()

    def finish(self) -> tuple[np.ndarray, int]:
        """``(decisions (n_frames,) bool, mode used)``: sample ``s`` inherits ``decisions[s // frame_len]``."""
        if self._rest.size:
            padded = np.zeros(self.frame_len, np.float32)
            padded[: self._rest.size] = self._rest
            self._classify(padded)
            self._rest = np.zeros(0, np.float32)
        last = self.length - (self.length - 1) // self.frame_len * self.frame_len if self.length else 0
        for mode, parts in zip(self.modes, self._decisions):  # noqa: B007  (the mode that stops the loop is returned)
            d = np.concatenate(parts) if parts else np.zeros(0, bool)
            active = int(d[:-1].sum()) * self.frame_len + (last if d.size and d[-1] else 0)
            if self.length and active / self.length >= self.min_active:
                break
        return d, int(mode)

    def sample_vad(self, decisions: np.ndarray, start: int, n: int) -> np.ndarray:
        """The per-sample VAD ``(n,)`` of samples ``start .. start + n`` from :meth:`finish`'s decisions."""
        return decisions[np.arange(start, start + n) // self.frame_len]
