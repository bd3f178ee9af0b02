"""The world a scanner sees: alignments, cross-section profiles, features, deformation
epochs, the tunnel mesh and its files, the generator, rock relief and the presets."""

from __future__ import annotations

from typing import TYPE_CHECKING

from raytrace.lazy import lazy_exports_of

# The one list of public names (imported on first use; type checkers read it).
if TYPE_CHECKING:
    from .alignment import Alignment, Element, arc, clothoid, curve, straight
    from .profiles import Profile, arched_rectangle, circle, horseshoe
    from .features import Bolts, Cable, Drainage, Niche, Prisms, WetFloor
    from .deformation import Bulge, Convergence, Ovalisation
    from .mesh import LABELS, REFLECTIVITY, TunnelMesh, read_axis, read_tunnel, write_ply, write_tunnel
    from .generator import edge_length_for, make_tunnel
    from .presets import PRESETS, preset
    from .rock import RockRelief
    from .junction import Branch, branch_alignment, make_junction_tunnel

__getattr__, __dir__, __all__ = lazy_exports_of(__name__, __file__, extra=())
