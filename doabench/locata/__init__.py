"""LOCATA corpus support: reader of the official layout, the ``locata`` task kind (tasks
locata-1, locata-3, locata-5), and the challenge's own measures (``measures``), submission format
(``submission``) and evaluation of a submission folder (``evaluate``, ``doabench locata-eval``).
The fixture writer for tests is tests/fixtures/locata.py; see docs/locata.md."""
from doabench.locata.layout import LOCATA_ENV, Recording, find_recordings, locata_root
from doabench.locata.reader import read_recording
from doabench.locata.source import LocataEpisodes

__all__ = ["LOCATA_ENV", "LocataEpisodes", "Recording", "find_recordings", "locata_root", "read_recording"]
