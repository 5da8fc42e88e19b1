"""doabench_baselines: Cross3D and the paper's learned baselines as doabench tracker plugins.

Modules (docs/models.md describes the architectures and how they match Table I):

* ``layers``    – spherical padding, causal convolutions with streaming caches
* ``cross3d``   – Cross3D (paper IV-B)
* ``cnn1d``     – ``gcc-cnn1d`` and ``max-cnn1d`` (paper V-A)
* ``cnn2d``     – ``spec-cnn2d`` (paper V-A)
* ``seldnet``   – SELDnet DOA-branch replica (paper V-A)
* ``streaming`` – :class:`StreamingRunner`, one frame in, one direction out; a whole episode in chunks
* ``weights``   – safetensors weight files with checked metadata and SHA256SUMS (:class:`WeightsFile`)
* ``catalog``   – which weights: the shipped ones by name (``paper``, ``moving``), their files and
  SHA-256, the default, and a tracker's weights file found by name, default or path (it builds on
  ``weights``, which never imports it; the trackers ask it)
* ``hold``      – the hold rule of the causal trackers in long silences
* ``device``    – the torch device a tracker runs on
* ``trackers``  – the registered trackers, one module each (importing one registers it; doabench
  finds them through the ``doabench.trackers`` entry points)

This package uses only doabench's public API (``doabench``, ``doabench.errors`` and
``doabench.trackers``), as a third-party plugin would. torch is imported when a tracker is built,
not when doabench lists the registered trackers.
"""
