"""Room simulator backends, one module each (registered in :mod:`doabench.acoustics.simulators`)."""
