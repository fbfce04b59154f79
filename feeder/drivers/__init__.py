"""Amplifier and sensor drivers.  They move bytes and frames, and know no physics."""
