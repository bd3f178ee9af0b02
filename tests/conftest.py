import numpy as np
import pytest

from raytrace.shapes import tunnel_tube


@pytest.fixture(scope="session")
def tunnel_120k():
    """A 300 m rough horseshoe tunnel of ~120k triangles, open portals, local coords."""
    v, f = tunnel_tube(120_000, length_m=300.0, roughness_m=0.002, seed=1)
    v[:, 0] -= 150.0
    return v, f
