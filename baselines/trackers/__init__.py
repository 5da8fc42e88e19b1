"""The learned trackers, one module each, built on doabench's public plugin API only.

Registered ids (``--tracker ID[:SPEC]`` with ``--tracker-opt key=value``), each declared in the
``doabench.trackers`` entry-point group, so doabench imports a tracker's module when its id is asked for:

* ``cross3d[:RES]``  – Cross3D on SRP maps (``srp``, ``srp_max``; :mod:`.cross3d`); RES defaults to the
  resolution of the catalog's default weights, else 8x16.
* ``gcc-cnn1d``      – 1D CNN on GCC-PHAT (``gcc``; :mod:`.gcc_cnn1d`); option ``array`` (default ``nao``).
* ``max-cnn1d[:RES]``– 1D CNN on the map maxima (``srp_max``; :mod:`.max_cnn1d`); RES defaults to 64x128.
* ``spec-cnn2d``     – causal 2D CNN on spectrograms (``spectrogram``, K = 4096; :mod:`.spec_cnn2d`).
* ``seldnet``        – SELDnet DOA replica on spectrograms (K = 512), offline (``track``; :mod:`.seldnet`).

Common options: ``weights=NAME|default|FILE`` (a name of the weights catalog, the default, or a
file; ``weights=random`` forces random initialisation), ``device=cpu|cuda[:N]``, ``seed=N``
(random initialisation), ``hold=auto|off|N`` (causal models: :mod:`doabench_baselines.hold`).
Untrained trackers say ``trained: false`` in ``describe()``. They can be built (``describe``,
docs, training from scratch), but ``doabench run``/``track``/``doabench.run`` refuse them unless
``weights=random`` was given explicitly (``allow_untrained``).

Causal trackers run one frame per ``step`` through a ``StreamingRunner``; their ``track`` streams
the episode in chunks and gives the same directions. What they share is :mod:`.neural`.
"""
