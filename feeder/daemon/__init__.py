"""The control daemon: closed-loop positioning over an amplifier link and a position sensor.

requests (each request's fields, job and reply) → service (queue, faults, reconnects) →
control_loop (fixed-rate tick) → policy (decisions) →
step_estimator (learned step per direction); store (SQLite); client (socket
client used by the CLI); config (TOML); launcher (starts firmware_sim).
"""
