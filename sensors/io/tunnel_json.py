"""The JSON of a tunnel: reading it, and where it lies beside a tunnel's PLY.

The format layer's part of a tunnel file (``FORMAT``, the sidecar's place, its JSON
object and CRS); ``survey.world.mesh`` (the tunnel files) and
``survey.world.alignment_io`` (every file a ``--tunnel`` option reads) build the
alignment and profile from it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sensors.io.errors import TunnelFileError

__all__ = ["FORMAT", "read_meta", "sidecar", "tunnel_crs"]

#: The ``format`` key of a tunnel JSON written by ``tunnelsim tunnel``.
FORMAT = "tunnelsim-tunnel/1"


def sidecar(path: str | Path) -> Path:
    """The JSON beside a tunnel's PLY (same name, ``.json``)."""
    return Path(path).with_suffix(".json")


def read_meta(js: str | Path) -> dict[str, Any]:
    """The JSON object of a tunnel sidecar; ``TunnelFileError`` for a missing, unreadable,
    undecodable or non-object file."""
    js = Path(js)
    if not js.is_file():
        raise TunnelFileError(f"Expected a tunnel JSON, got '{js}' which does not exist.")
    try:
        meta = json.loads(js.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TunnelFileError(f"Expected a JSON tunnel description in '{js}', got a file "
                              f"that does not parse ({exc}); rewrite it with "
                              "'tunnelsim tunnel'.") from None
    if not isinstance(meta, dict):
        raise TunnelFileError(f"Expected a JSON object in '{js}', got a "
                              f"{type(meta).__name__}; rewrite it with 'tunnelsim tunnel'.")
    return meta


def tunnel_crs(meta: Mapping[str, Any]) -> str | None:
    """The ``crs`` (WKT) of a tunnel's metadata, or None for a local tunnel; a ``crs``
    that is not a non-empty string is a ``TunnelFileError``."""
    crs = meta.get("crs")
    if crs is None:
        return None
    if not isinstance(crs, str) or not crs.strip():
        raise TunnelFileError(f"Expected the tunnel's 'crs' as WKT text, got {crs!r}; "
                              "rewrite the JSON with 'tunnelsim tunnel --crs'.")
    return crs
