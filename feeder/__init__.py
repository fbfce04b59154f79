"""Piezo-driven inertial (stick-slip) micro-feeder.

Data flows one way: physics (``contact``, ``surface``, ``friction``, ``plant``)
← ``planner`` ← ``daemon``.  ``drivers`` talk to amplifiers and sensors and
know nothing of physics.  ``firmware_sim`` (a separate program) plays the
amplifier firmware and the physical world.
"""

__version__ = "0.1.0"
