"""Surfaces: parameters of the equivalent rough surface, read from TOML or measured from AFM scans."""
