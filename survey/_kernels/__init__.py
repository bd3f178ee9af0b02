"""Private Numba kernels of the survey layer."""
