"""Numba kernels of the sensor simulation (private)."""
