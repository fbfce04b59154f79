"""The control daemon: closed-loop positioning over an amplifier link and a position sensor.

service (socket, faults, persistence) → control_loop (fixed-rate tick) →
step_estimator (learned step per direction); store (SQLite); client (socket
client used by the CLI); config (TOML); launcher (starts firmware_sim).
"""
