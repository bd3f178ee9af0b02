"""survey: the surveyor's workflow: alignments, generated tunnels, control points and
Helmert adjustment, MLS drift correction, and the ``tunnelsim`` command."""

from .alignment import Alignment, arc, clothoid, curve, straight
from .drift import fit_drift, leave_one_out
from .helmert import HelmertResult, fit_helmert
from .profiles import Profile, arched_rectangle, circle, horseshoe
from .tunnel import TunnelMesh, make_tunnel
from .tunnel_io import read_tunnel

__all__ = ["Alignment", "straight", "arc", "clothoid", "curve", "Profile", "circle",
           "horseshoe", "arched_rectangle", "make_tunnel", "TunnelMesh", "read_tunnel",
           "fit_helmert", "HelmertResult", "fit_drift", "leave_one_out"]
