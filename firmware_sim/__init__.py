"""The amplifier firmware simulator: ``python -m firmware_sim`` (DESIGN §5–6)."""
