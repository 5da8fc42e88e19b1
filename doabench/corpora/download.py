"""Download and unpack LibriSpeech subsets from OpenSLR (resource 12).

``download_librispeech("test-clean", dest)`` fetches ``<base_url>/test-clean.tar.gz`` into
``dest/test-clean.tar.gz.part``, resuming an earlier partial download with an HTTP Range request
(a server that ignores Range restarts it from zero), retries a dropped connection ``retries``
times, checks the MD5 published by OpenSLR (``md5sum.txt`` of resource 12, copied in
``PUBLISHED_MD5``), and unpacks into a temporary folder inside ``dest`` that is renamed to
``dest/LibriSpeech/<subset>`` only when the whole archive has been extracted. A checksum mismatch
deletes the bad archive (the next run starts afresh) and leaves nothing extracted. The archive is
deleted after a successful extraction unless ``keep_archive``.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import tarfile
import tempfile
import urllib.error
import urllib.request
from pathlib import Path

from doabench.corpora.speech import LIBRISPEECH_SUBSETS
from doabench.errors import ConfigError, DoabenchError, InputError, OutputError

DEFAULT_BASE_URL = "https://www.openslr.org/resources/12"
# As published by OpenSLR in https://www.openslr.org/resources/12/md5sum.txt.
PUBLISHED_MD5 = {
    "dev-clean": "42e2234ba48799c1f50f24a7926300a1",
    "dev-other": "c8d0bcc9cca99d4f8b62fcc847357931",
    "test-clean": "32fa31d27d2e1cad72775fee3f4849a9",
    "test-other": "fb5a50374b501bb3bac4815ee91d3135",
    "train-clean-100": "2a93770f6d5c6c964bc36631d331a522",
    "train-clean-360": "c0e676e450a7ff2f54aeade5171606fa",
    "train-other-500": "d1a0fd59409feb2c614ce4d30c387708",
}
CHUNK = 1 << 20


class DownloadError(DoabenchError, OSError):
    """A download failed (network, server or checksum); the message says how to continue."""


def _md5(path: Path) -> str:
    h = hashlib.md5()
    with open(path, "rb") as f:
        while block := f.read(CHUNK):
            h.update(block)
    return h.hexdigest()


def _fetch(url: str, part: Path, progress: bool, timeout: float) -> None:
    """Append the rest of ``url`` to ``part`` (HTTP Range from its current size)."""
    from tqdm import tqdm

    have = part.stat().st_size if part.exists() else 0
    request = urllib.request.Request(url, headers={"Range": f"bytes={have}-"} if have else {})
    try:
        response = urllib.request.urlopen(request, timeout=timeout)
    except urllib.error.HTTPError as exc:
        if exc.code == 416 and have:  # nothing left to fetch: the part file is already complete
            return
        raise DownloadError(f"{url}: HTTP {exc.code} {exc.reason}") from None
    with response:
        if have and response.status != 206:  # the server ignored Range: start again
            have = 0
        length = response.headers.get("Content-Length")
        total = have + int(length) if length is not None else None
        with open(part, "ab" if have else "wb") as f, tqdm(
            total=total, initial=have, unit="B", unit_scale=True, unit_divisor=1024,
            desc=part.name.removesuffix(".part"), disable=not progress,
        ) as bar:
            while block := response.read(CHUNK):
                try:
                    f.write(block)
                except OSError as exc:  # a full disk or quota is not a network error: no retry
                    raise OutputError(f"cannot write {part}: {exc.strerror or exc}; what was downloaded is "
                                      "kept, run the same command again to resume") from None
                bar.update(len(block))
        if total is not None and part.stat().st_size < total:
            raise ConnectionError(f"connection closed after {part.stat().st_size} of {total} bytes")


def download_file(url: str, target: Path, md5: str | None, retries: int = 3, progress: bool = True,
                  timeout: float = 60.0) -> Path:
    """Download ``url`` to ``target`` (resumable via ``target.part``) and check its MD5."""
    part = target.with_name(target.name + ".part")
    if not target.exists():
        for attempt in range(retries + 1):
            try:
                _fetch(url, part, progress, timeout)
                break
            except (ConnectionError, TimeoutError, urllib.error.URLError, OSError) as exc:
                if isinstance(exc, (DownloadError, OutputError)):
                    raise
                if attempt == retries:
                    size = part.stat().st_size if part.exists() else 0
                    if size == 0:
                        raise DownloadError(f"download of {url} failed ({exc}); check the network or try "
                                            "another --base-url mirror") from None
                    raise DownloadError(
                        f"download of {url} interrupted after {size} bytes ({exc}); run the same command "
                        "again to resume") from None
        part.replace(target)
    if md5 is not None:
        got = _md5(target)
        if got != md5.lower():
            target.unlink()
            raise DownloadError(f"{target.name}: MD5 {got} does not match the published {md5}; the file was "
                                "deleted, run the command again (or use another --base-url mirror)")
    return target


def _safe_extractall(tar: tarfile.TarFile, into: Path) -> None:
    """Extract refusing absolute paths, ``..`` and links (tarfile's "data" filter when present)."""
    if hasattr(tarfile, "data_filter"):  # Python >= 3.10.12 / 3.11.4
        tar.extractall(into, filter="data")
        return
    for m in tar.getmembers():
        parts = Path(m.name).parts
        if m.name.startswith("/") or ".." in parts or not (m.isfile() or m.isdir()):
            raise tarfile.TarError(f"refusing archive member {m.name!r}")
    tar.extractall(into)


def _extract(archive: Path, dest: Path, subset: str) -> Path:
    """Unpack ``archive`` into a temporary folder of ``dest`` and move the subset into place."""
    final = dest / "LibriSpeech" / subset
    tmp = Path(tempfile.mkdtemp(prefix=f".extract-{subset}-", dir=dest))
    try:
        try:
            with tarfile.open(archive, "r:*") as tar:
                _safe_extractall(tar, tmp)
        except (tarfile.TarError, OSError, EOFError) as exc:
            raise InputError(f"{archive.name}: cannot extract ({exc})") from None
        src = tmp / "LibriSpeech" / subset
        if not src.is_dir():
            raise InputError(f"{archive.name} does not contain LibriSpeech/{subset}/")
        final.parent.mkdir(parents=True, exist_ok=True)
        for extra in (tmp / "LibriSpeech").iterdir():  # README/LICENSE/SPEAKERS... next to the subsets
            if extra.is_file() and not (final.parent / extra.name).exists():
                extra.replace(final.parent / extra.name)
        src.replace(final)  # atomic on one filesystem: the subset appears complete or not at all
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return final


def download_librispeech(subset: str, dest: str | os.PathLike = "data", base_url: str = DEFAULT_BASE_URL,
                         md5: str | None = None, keep_archive: bool = False, force: bool = False,
                         retries: int = 3, progress: bool = True, timeout: float = 60.0) -> Path:
    """Download and unpack one official LibriSpeech subset; returns ``dest/LibriSpeech/<subset>``.

    ``md5``: expected checksum (default: the published one). Skips the work when the subset folder
    already exists, unless ``force``.
    """
    if subset not in LIBRISPEECH_SUBSETS:
        raise ConfigError(f"unknown LibriSpeech subset {subset!r} (official: {', '.join(LIBRISPEECH_SUBSETS)})")
    dest = Path(dest).expanduser()
    final = dest / "LibriSpeech" / subset
    if final.is_dir() and not force:
        return final
    try:
        dest.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create destination {dest}: {exc.strerror}") from None
    archive = dest / f"{subset}.tar.gz"
    url = f"{base_url.rstrip('/')}/{subset}.tar.gz"
    download_file(url, archive, md5 or PUBLISHED_MD5[subset], retries=retries, progress=progress, timeout=timeout)
    if final.is_dir():  # --force: replace the old copy only once the new one is unpacked
        old = final.with_name(f".old-{subset}")
        final.replace(old)
        try:
            _extract(archive, dest, subset)
        except BaseException:
            old.replace(final)
            raise
        shutil.rmtree(old, ignore_errors=True)
    else:
        _extract(archive, dest, subset)
    if not keep_archive:
        archive.unlink()
    return final
