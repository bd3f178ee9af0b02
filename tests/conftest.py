import os

import pytest
from hypothesis import settings

# CI runs the same examples every time (reproducible, no flaky landings); local runs
# explore new ones. Hypothesis's documented recommendation for CI.
settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")

from raytrace.config import threading_info
from raytrace.shapes import tunnel_tube

# Numba picks its threading layer at the first parallel kernel. Test modules import
# Open3D at collection, whose bundled TBB is older than Numba accepts, and Numba then
# warns once where it first launches one (the CLI does the same before Open3D loads).
threading_info()


@pytest.fixture(scope="session")
def tunnel_120k():
    """A 300 m rough horseshoe tunnel of ~120k triangles, open portals, local coords."""
    v, f = tunnel_tube(120_000, length_m=300.0, roughness_m=0.002, seed=1)
    v[:, 0] -= 150.0
    return v, f
