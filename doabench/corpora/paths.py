"""Where the corpora are: one rule for a path given by flag, Python keyword, task option or environment.

Precedence, the same for every command and for the Python API:

1. an explicit path: ``--librispeech`` / ``--locata-root`` on the command line, or the
   ``librispeech=`` / ``locata_root=`` keyword of ``doabench.run``, ``DoaEnv``,
   ``gymnasium.make``, ``make_dataset`` and the episode sources (a task's run-time options);
2. else the environment variable ``DOABENCH_LIBRISPEECH`` / ``DOABENCH_LOCATA``;
3. else none: a task that needs the corpus stops with a one-line error saying how to give it
   (``doabench simulate`` without a task uses the embedded speech clips).

An empty string counts as not given. What is then done with the path (which LibriSpeech subset,
which LOCATA split) does not depend on where the path came from.
"""
from __future__ import annotations

import os

LIBRISPEECH_ENV = "DOABENCH_LIBRISPEECH"
LOCATA_ENV = "DOABENCH_LOCATA"
CORPUS_ENV = {"librispeech": LIBRISPEECH_ENV, "locata": LOCATA_ENV}


def corpus_root(corpus: str, given: str | os.PathLike | None = None) -> str | None:
    """The root of ``corpus`` (``librispeech`` or ``locata``) by the precedence above, or None."""
    if given is not None and os.fspath(given) != "":
        return os.fspath(given)
    return os.environ.get(CORPUS_ENV[corpus]) or None
