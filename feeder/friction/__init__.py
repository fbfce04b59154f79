"""Friction from AFM force curves (paper §IV–V): cantilever presets, static-friction peaks, τ = F/A_r.

- :mod:`~feeder.friction.cantilevers`: the paper's cantilevers (Table II).
- :mod:`~feeder.friction.force_curves`: the force-curve CSV format and its analysis
  (contact onset, static-friction peak before sliding, sliding level).
- :mod:`~feeder.friction.synthetic_curves`: realistic generated curves with a known peak.
- :mod:`~feeder.friction.shear_strength`: τ = F/A_r with its uncertainty band.
"""
