"""Plain-data records of the world's dataclasses: ``{"kind": name, **fields}``, the form
the tunnel JSON stores features and deformations in."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["from_record"]


def from_record(d: Mapping[str, Any], kinds: Mapping[str, type], error: type[ValueError],
                what: str) -> Any:
    """The object of a ``{"kind": ..., **fields}`` record, ``kinds[kind](**fields)``;
    ``error`` names the kinds or the fields expected when the record does not fit."""
    fields = dict(d)
    kind = fields.pop("kind", None)
    if kind not in kinds:
        raise error(f"Expected a {what} kind in {sorted(kinds)}, got {kind!r}.")
    try:
        return kinds[kind](**fields)
    except TypeError as exc:
        raise error(f"Expected the fields of a {kind} {what}, got {sorted(fields)} "
                    f"({exc}).") from exc
