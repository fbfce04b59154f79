"""What the host and the amplifier firmware agree on, as data, in one place.

Both sides read these modules: the host drivers (:mod:`feeder.drivers`) and
``firmware_sim`` (which may import ``feeder``; never the reverse).
"""
