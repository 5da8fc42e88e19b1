"""Corpora: where source signals and their voice activity come from, apart from room acoustics.

* :mod:`.speech`: speech sources (LibriSpeech in its official layout, the embedded demo clips);
* :mod:`.vad`: the WebRTC voice activity detector the paper uses;
* :mod:`.download`: resumable, checksummed corpus downloads (`doabench data download`).
"""
