"""Surfaces: parameters of the equivalent rough surface, read from TOML or measured from AFM scans.

- :mod:`~feeder.surface.parameters`: the GW surface (σ, R, η, μ, material) and its TOML file.
- :mod:`~feeder.surface.reading`: height maps in metres from AFM instrument files
  (SurfaceTopography, the ``afm`` extra) and plain ``.npy``/text arrays.
- :mod:`~feeder.surface.statistics`: plane removal, 8-neighbour summits, Sq, μ, η, R
  (paper eqs. 12–14) and the equivalent surface of two scans (eqs. 1, 3).
"""
