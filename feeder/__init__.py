"""Piezo-driven inertial (stick-slip) micro-feeder.

Data flows one way: physics (``contact``, ``surface``, ``friction``, ``plant``)
← ``planner`` ← ``daemon``.  ``drivers`` talk to amplifiers and sensors and
know nothing of physics.  ``firmware_sim`` (a separate program) plays the
amplifier firmware and the physical world.

``from feeder import Client``: the typed client of a running daemon
(:mod:`feeder.daemon.client`; light to import, no numpy).
"""

from feeder.daemon.client import Client

__all__ = ["Client"]
__version__ = "0.1.0"
