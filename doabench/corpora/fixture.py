"""A LibriSpeech-layout folder made of the embedded synthetic clips, for runs without the corpus.

``doabench train`` and the LibriSpeech readers need a folder in the official layout
(``<subset>/<speaker>/<chapter>/<speaker>-<chapter>-<utterance>.flac``). Where the corpus is not at
hand (a GPU machine lent for a throughput check, the CUDA tests), this writes one from the six
clips shipped in ``doabench/data/speech``. The clips sound nothing like LibriSpeech: use the
folder for smoke runs and timings (a trajectory costs the same whatever it says), never to train
a model that is evaluated or shipped.
"""
from __future__ import annotations

import shutil
from importlib import resources
from pathlib import Path

from doabench.errors import ConfigError

SUBSETS = ("train-clean-100", "test-other")


def write_librispeech_layout(root: str | Path, subsets: tuple[str, ...] = SUBSETS, speakers: int = 10,
                             utterances: int = 3) -> Path:
    """Write ``root/<subset>/<speaker>/<chapter>/*.flac`` from the embedded clips and return ``root``.

    Each subset gets ``speakers`` speakers (ids distinct across subsets, so training and test
    speakers never overlap), one chapter each, ``utterances`` clips per chapter (the six clips in
    turn). An existing file is left as it is, so the call can be repeated."""
    if speakers < 1 or utterances < 1:
        raise ConfigError(f"a LibriSpeech-layout fixture needs at least one speaker and one utterance, got "
                          f"speakers={speakers}, utterances={utterances}")
    folder = resources.files("doabench.data") / "speech"
    clips = sorted((e for e in folder.iterdir() if e.name.endswith(".flac")), key=lambda e: e.name)
    root = Path(root)
    for n, subset in enumerate(subsets):
        for s in range(speakers):
            speaker, chapter = 1000 * (n + 1) + s, 100 + s
            target = root / subset / str(speaker) / str(chapter)
            target.mkdir(parents=True, exist_ok=True)
            for u in range(utterances):
                path = target / f"{speaker}-{chapter}-{u:04d}.flac"
                if not path.exists():
                    with resources.as_file(clips[(s * utterances + u) % len(clips)]) as clip:
                        shutil.copyfile(clip, path)
    return root
