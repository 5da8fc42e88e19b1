"""Speech sources, WebRTC VAD and the LibriSpeech downloader."""
from __future__ import annotations

import hashlib
import http.server
import io
import tarfile
import threading
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from conftest import LIBRISPEECH, LIBRISPEECH_MISSING, SHARED_LIBRISPEECH
from doabench.corpora import vad as vad_mod
from doabench.corpora.download import DownloadError, download_librispeech
from doabench.corpora.speech import (
    EmbeddedSpeechSource,
    LibriSpeechSource,
    SpeechSource,
    get_speech_source,
    resolve_librispeech,
)
from doabench.corpora.vad import clean_with_vad, webrtc_vad
from doabench.errors import ConfigError, NotFoundError

FS = 16000
LIBRI = LIBRISPEECH or SHARED_LIBRISPEECH  # DOABENCH_LIBRISPEECH, else ../shared/data/LibriSpeech
needs_libri = pytest.mark.skipif(LIBRISPEECH is None, reason=LIBRISPEECH_MISSING)


# --------------------------------------------------------------------------- VAD


def _bursts(kind: str, rng) -> np.ndarray:
    """1 s silence, 1 s burst, 1 s silence (3 s)."""
    x = np.zeros(3 * FS)
    t = np.arange(FS) / FS
    x[FS : 2 * FS] = 0.3 * np.sin(2 * np.pi * 300 * t) if kind == "tone" else 0.1 * rng.standard_normal(FS)
    return x


@pytest.mark.parametrize("kind", ["tone", "noise"])
def test_vad_on_silence_and_bursts_falls_back_to_mode_1(kind):
    x = _bursts(kind, np.random.default_rng(0))
    vad, mode = webrtc_vad(x, FS)
    assert vad.shape == x.shape and vad.dtype == bool
    assert mode == 1  # only a third is active: no mode reaches 66 %, the last one is kept
    # Silence stays silent (WebRTC keeps a ~150 ms hangover after a burst).
    assert not vad[: FS - 1600].any() and not vad[2 * FS + 4000 :].any()
    assert vad[FS + 1600 : 2 * FS - 1600].mean() > 0.5
    cleaned, vad2, _ = clean_with_vad(x, FS)
    assert cleaned.dtype == np.float32 and np.array_equal(vad, vad2)
    assert np.all(cleaned[~vad] == 0) and np.allclose(cleaned[vad], x[vad], atol=1e-7)


def test_vad_keeps_mode_3_when_enough_is_active():
    x = 0.1 * np.random.default_rng(1).standard_normal(2 * FS)
    vad, mode = webrtc_vad(x, FS)
    assert mode == 3 and vad.mean() >= 0.66


def test_vad_fallback_order(monkeypatch):
    # Fake per-mode decisions: mode 3 keeps 50 %, mode 2 keeps 70 % -> mode 2 is chosen.
    calls = []

    def fake(frames, fs, mode):
        calls.append(mode)
        frac = {3: 0.5, 2: 0.7, 1: 0.9}[mode]
        return np.arange(len(frames)) < frac * len(frames)

    monkeypatch.setattr(vad_mod, "_frame_decisions", fake)
    vad, mode = webrtc_vad(np.zeros(FS), FS)
    assert (mode, calls) == (2, [3, 2]) and abs(vad.mean() - 0.7) < 0.01


def test_vad_odd_length_and_bad_input():
    vad, _ = webrtc_vad(np.zeros(1234), FS)
    assert vad.shape == (1234,)
    with pytest.raises(ConfigError, match="sample rate"):
        webrtc_vad(np.zeros(100), 22050)
    with pytest.raises(ConfigError, match="mono"):
        webrtc_vad(np.zeros((2, 100)), FS)


# --------------------------------------------------------------------------- embedded clips


def test_embedded_source_chunks():
    src = EmbeddedSpeechSource()
    assert isinstance(src, SpeechSource)
    assert 3 <= len(src.clip_names) <= 6
    folder = Path(__file__).resolve().parents[1] / "doabench" / "data" / "speech"
    assert sum(p.stat().st_size for p in folder.glob("*.flac")) < 1_000_000
    chunk = src.sample(np.random.default_rng(3), 7.5, FS)
    assert chunk.signal.shape == (120000,) and chunk.signal.dtype == np.float32
    assert chunk.vad.shape == (120000,) and 0.3 < chunk.vad.mean() < 1.0
    assert np.all(chunk.signal[~chunk.vad] == 0)
    again = src.load(chunk.info)
    assert np.array_equal(again.signal, chunk.signal) and np.array_equal(again.vad, chunk.vad)
    other = src.sample(np.random.default_rng(4), 7.5, FS)
    assert not np.array_equal(other.signal, chunk.signal)


def test_default_source_is_embedded_without_librispeech(monkeypatch):
    monkeypatch.delenv("DOABENCH_LIBRISPEECH", raising=False)
    assert isinstance(get_speech_source(None), EmbeddedSpeechSource)


def test_embedded_source_other_rate():
    chunk = EmbeddedSpeechSource().sample(np.random.default_rng(0), 1.0, 8000)
    assert chunk.signal.shape == (8000,)


# --------------------------------------------------------------------------- LibriSpeech


@needs_libri
def test_librispeech_chunks_from_shared_subset():
    src = LibriSpeechSource(LIBRI, "test-other")
    assert not list(src.root.rglob("*.trans.txt"))  # the shared copy has no transcripts
    chunk = src.sample(np.random.default_rng(0), 20.0, FS)
    info = chunk.info
    assert chunk.signal.shape == (320000,) and chunk.vad.shape == (320000,)
    assert info["corpus"] == "librispeech" and info["subset"] == "test-other" and info["length"] == 320000
    # Rebuild the raw chunk by hand: consecutive utterances, mean removed, silence zeroed.
    raw = np.concatenate([sf.read(str(src.root / f))[0] for f in info["files"]])
    raw = raw[info["start"] : info["start"] + 320000]
    raw = raw - raw.mean()
    assert np.allclose(chunk.signal, np.where(chunk.vad, raw, 0), atol=1e-6)
    assert all(f.split("/")[0] == info["speaker"] for f in info["files"])  # chapters are long here
    assert np.array_equal(src.load(info).signal, chunk.signal)


@needs_libri
@pytest.mark.skipif(not (LIBRI / "train-clean-100").is_dir() or LIBRI.name != "LibriSpeech",
                    reason=f"the LibriSpeech root {LIBRI} has no train-clean-100 subset or is not named LibriSpeech")
def test_librispeech_short_chapters_concatenate_and_root_forms(monkeypatch):
    src = LibriSpeechSource(LIBRI / "train-clean-100")  # the subset folder itself
    assert src.subset == "train-clean-100"
    chunk = src.sample(np.random.default_rng(1), 20.0, FS)  # one short utterance per chapter here
    assert chunk.signal.shape == (320000,) and len(chunk.info["files"]) >= 2 and chunk.info["start"] == 0
    assert resolve_librispeech(LIBRI.parent, "test-other")[1] == "test-other"  # folder holding LibriSpeech/
    monkeypatch.setenv("DOABENCH_LIBRISPEECH", str(LIBRI))
    assert LibriSpeechSource(None, "test-other").subset == "test-other"
    with pytest.raises(ConfigError, match="several LibriSpeech subsets"):
        LibriSpeechSource(LIBRI)


def test_librispeech_missing_path_says_how_to_get_it(tmp_path, monkeypatch):
    monkeypatch.delenv("DOABENCH_LIBRISPEECH", raising=False)
    with pytest.raises(NotFoundError, match="doabench data download librispeech --subset test-clean"):
        LibriSpeechSource(None, "test-clean")
    with pytest.raises(NotFoundError, match="does not exist.*openslr.org/12"):
        LibriSpeechSource(tmp_path / "nope", "test-clean")
    with pytest.raises(NotFoundError, match="no LibriSpeech audio"):
        LibriSpeechSource(tmp_path)  # exists but empty


# --------------------------------------------------------------------------- downloader


def _tiny_archive() -> bytes:
    buf = io.BytesIO()
    audio = io.BytesIO()
    sf.write(audio, 0.1 * np.sin(np.arange(8000) / 5.0), FS, format="FLAC")
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        for name, data in [("LibriSpeech/README.TXT", b"tiny test corpus\n"),
                           ("LibriSpeech/test-clean/1/2/1-2-0000.flac", audio.getvalue())]:
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return buf.getvalue()


class _Server:
    """A local HTTP server with Range support that can drop the first transfer half-way."""

    def __init__(self, payload: bytes, drop_first: bool = False):
        self.payload, self.drop_first, self.ranges = payload, drop_first, []
        outer = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_GET(self):
                rng = self.headers.get("Range")
                outer.ranges.append(rng)
                start = int(rng.split("=")[1].rstrip("-")) if rng else 0
                body = outer.payload[start:]
                self.send_response(206 if rng else 200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                if outer.drop_first:
                    outer.drop_first = False
                    self.wfile.write(body[: len(body) // 2])
                    self.wfile.flush()
                    self.close_connection = True
                    return
                self.wfile.write(body)

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def tiny():
    payload = _tiny_archive()
    servers = []

    def make(drop_first=False):
        servers.append(_Server(payload, drop_first))
        return servers[-1]

    yield payload, hashlib.md5(payload).hexdigest(), make
    for s in servers:
        s.close()


def test_download_resumes_after_interruption(tmp_path, tiny):
    payload, md5, make = tiny
    server = make(drop_first=True)
    with pytest.raises(DownloadError, match="run the same command again to resume"):
        download_librispeech("test-clean", tmp_path, base_url=server.url, md5=md5, retries=0,
                             progress=False, timeout=5)
    part = tmp_path / "test-clean.tar.gz.part"
    assert 0 < part.stat().st_size < len(payload) and not (tmp_path / "LibriSpeech").exists()
    final = download_librispeech("test-clean", tmp_path, base_url=server.url, md5=md5, retries=0,
                                 progress=False, timeout=5)
    assert server.ranges[-1] == f"bytes={len(payload) // 2}-"
    assert final == tmp_path / "LibriSpeech" / "test-clean"
    assert (final / "1" / "2" / "1-2-0000.flac").is_file() and (final.parent / "README.TXT").is_file()
    assert not part.exists() and not (tmp_path / "test-clean.tar.gz").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".extract")]
    assert LibriSpeechSource(tmp_path / "LibriSpeech", "test-clean").chapters == [("1", "2")]


def test_download_retries_within_one_call(tmp_path, tiny):
    payload, md5, make = tiny
    server = make(drop_first=True)
    download_librispeech("test-clean", tmp_path, base_url=server.url, md5=md5, retries=1, progress=False,
                         timeout=5)
    assert server.ranges == [None, f"bytes={len(payload) // 2}-"]


def test_download_checksum_mismatch_leaves_nothing(tmp_path, tiny):
    _, _, make = tiny
    server = make()
    with pytest.raises(DownloadError, match="does not match the published"):
        download_librispeech("test-clean", tmp_path, base_url=server.url, md5="0" * 32, progress=False, timeout=5)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_download_unknown_subset(tmp_path):
    with pytest.raises(ConfigError, match="unknown LibriSpeech subset"):
        download_librispeech("test-dirty", tmp_path)


def test_the_librispeech_layout_fixture_reads_as_the_corpus(tmp_path):
    """The embedded clips laid out as LibriSpeech (for GPU checks without the corpus) are read by the
    corpus reader, with distinct speakers per subset; writing again changes nothing."""
    from doabench.corpora.fixture import write_librispeech_layout
    from doabench.corpora.speech import LibriSpeechSource
    from doabench.errors import ConfigError

    root = write_librispeech_layout(tmp_path / "LibriSpeech", speakers=3, utterances=2)
    files = sorted(root.rglob("*.flac"))
    assert len(files) == 12
    stamps = [f.stat().st_mtime_ns for f in files]
    write_librispeech_layout(root, speakers=3, utterances=2)
    assert [f.stat().st_mtime_ns for f in files] == stamps
    train = {s for s, _ in LibriSpeechSource(root, "train-clean-100").chapters}
    test = {s for s, _ in LibriSpeechSource(root, "test-other").chapters}
    assert len(train) == len(test) == 3 and not train & test
    chunk = LibriSpeechSource(root, "train-clean-100").sample(np.random.default_rng(0), 20.0)
    assert chunk.signal.shape == (320000,) and np.abs(chunk.signal).max() > 0
    with pytest.raises(ConfigError, match="at least one speaker"):
        write_librispeech_layout(root, speakers=0)
