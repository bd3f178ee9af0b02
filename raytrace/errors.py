"""Exception tree shared by all tunnelsim packages.

``TunnelsimError`` is the root; callers that need to tell problems apart catch the
subclasses. Every subclass of a validation problem is also a ``ValueError`` so that
generic code (``except ValueError``) keeps working.

Messages follow one pattern: what was expected, what was got, what to do, e.g.
"Expected `origins` to have shape (n, 3), got (5, 2); pass one row per ray."
"""

from __future__ import annotations


class TunnelsimError(Exception):
    """Root of every error raised on purpose by tunnelsim."""


class MeshError(TunnelsimError, ValueError):
    """A triangle mesh is unusable (bad shapes, non-finite vertices, bad indices, empty)."""


class RayError(TunnelsimError, ValueError):
    """Rays given to a query are unusable (bad shapes, zero-length directions, NaN)."""


class SceneFileError(TunnelsimError, ValueError):
    """A saved scene file is missing, truncated or of another format version."""


class ConfigError(TunnelsimError, ValueError):
    """An engine setting is out of range: a thread count, a BVH build constant, or the
    ``TUNNELSIM_THREADS`` environment variable."""


__all__ = ["TunnelsimError", "MeshError", "RayError", "SceneFileError", "ConfigError"]
