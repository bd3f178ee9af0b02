"""The one loader of device and platform descriptions (TOML): typed reads that name the
file, table and key of every problem, unknown keys refused with the likeliest intended
one, and a catalogue of the shipped files by name.

Sensors (``sensors.spec``), platforms (``sensors.platform_spec``) and any later kind of
description are read through it; each says only what its tables hold and how the
values become its dataclasses. The rule that a key the loader does not read is an
error, not a silent default, is pbrt-v4's ``ParameterDictionary::ReportUnused`` (Pharr,
Jakob & Humphreys, *Physically Based Rendering*, 4th ed., appendix C.2) and HELIOS++'s
XSD check.

>>> t = SpecTable({"rate_hz": 10}, "my.toml", "spinning", SensorSpecError, "sensor",
...               valid=("rate_hz", "channels"))
>>> t.num("rate_hz", positive=True)
10.0
>>> SpecTable({"rate_hx": 10}, "my.toml", "spinning", SensorSpecError, "sensor",
...           valid=("rate_hz",))   # doctest: +ELLIPSIS
Traceback (most recent call last):
...
sensors.errors.SensorSpecError: Expected only known keys in table [spinning] of my.toml, got unknown key `rate_hx` (did you mean `rate_hz`?); valid keys there: rate_hz.
"""

from __future__ import annotations

import difflib
import math
import os
import tomllib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np
from numpy.typing import NDArray

from .errors import SensorSpecError, TunnelsimError  # noqa: F401  (the doctest raises it)

__all__ = ["Catalogue", "SpecTable", "read_toml"]

T = TypeVar("T")
ErrorType = type[TunnelsimError]


def read_toml(path: Path, error: ErrorType, kind: str) -> dict[str, Any]:
    """The TOML document at ``path``; ``error`` naming the file for a syntax error or
    an unreadable file (``kind``: "sensor", "platform" ... for the advice)."""
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise error(f"Expected valid TOML in {path}, got a syntax error: {exc}; "
                    f"fix the {kind} file.") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"Expected a readable UTF-8 text file at '{path}', got "
                    f"{type(exc).__name__}: {exc}.") from exc


class SpecTable:
    """Typed access to one TOML table, with errors naming the file, table and key.

    Parameters
    ----------
    data : dict
        The table's contents.
    file : str
        The file's name, for messages.
    table : str
        The table's dotted name ("" for the top level).
    error : type of TunnelsimError
        The class raised (``SensorSpecError``, ``PlatformError`` ...).
    kind : str
        What the file describes, for the advice ("fix the sensor file.").
    valid : sequence of str, optional
        The keys the table may hold (default: ``schema[table]``, if listed); any
        other is refused, naming the likeliest intended key (in this table, or in
        another table of ``schema``).
    required : bool
        Every key of ``valid`` must be present.
    schema : mapping of table name to keys, optional
        The keys of every table of the file, by dotted table name; a table not listed
        is free-form.
    """

    def __init__(self, data: Any, file: str, table: str, error: ErrorType, kind: str, *,
                 valid: Sequence[str] | None = None, required: bool = False,
                 schema: Mapping[str, Sequence[str]] | None = None) -> None:
        if not isinstance(data, dict):
            raise error(f"Expected [{table}] in {file} to be a table, got {data!r}; "
                        f"fix the {kind} file.")
        self.data, self.file, self.table = data, file, table
        self.error, self.kind = error, kind
        self._schema = schema or {}
        if valid is None:
            valid = self._schema.get(table)
        if valid is not None:
            self._refuse_unknown(tuple(valid))
            if required:
                missing = [k for k in valid if k not in data]
                if missing:
                    what = "table" if not table else "key"
                    raise error(f"Expected a {what} `{missing[0]}` in "
                                f"{f'[{table}] of ' if table else ''}{file}, got none; "
                                f"add it to the {kind} file.")

    # ------------------------------------------------------------------ messages
    def where(self, key: str) -> str:
        """The dotted name of ``key`` in this table."""
        return f"{self.table}.{key}" if self.table else key

    def err(self, key: str, what: str, got: object) -> TunnelsimError:
        """The error for a value of ``key`` that is not ``what``."""
        return self.error(f"Expected `{self.where(key)}` in {self.file} to be {what}, "
                          f"got {got!r}; fix the {self.kind} file.")

    def _refuse_unknown(self, valid: tuple[str, ...]) -> None:
        unknown = [k for k in self.data if k not in valid]
        if not unknown:
            return
        named = [f"`{k}`{self._guess(k, valid)}" for k in unknown]
        where = f"table [{self.table}]" if self.table else "the top level"
        raise self.error(
            f"Expected only known keys in {where} of {self.file}, got unknown "
            f"key{'s' if len(unknown) > 1 else ''} {', '.join(named)}; valid keys there: "
            f"{', '.join(valid)}.")

    def _guess(self, key: str, valid: Sequence[str]) -> str:
        near = difflib.get_close_matches(key, valid, n=1)
        if near:
            return f" (did you mean `{near[0]}`?)"
        for other, keys in self._schema.items():
            near = difflib.get_close_matches(key, keys, n=1, cutoff=0.8)
            if other != self.table and near:
                return f" (did you mean `{near[0]}` in [{other}]?)"
        return ""

    # ------------------------------------------------------------------ reads
    def raw(self, key: str) -> Any:
        """The value of ``key`` as TOML gave it; an error if it is missing."""
        if key not in self.data:
            raise self.error(f"Expected a field `{self.where(key)}` in {self.file}, "
                             f"got none; add it to the {self.kind} file.")
        return self.data[key]

    def num(self, key: str, lo: float | None = None, hi: float | None = None,
            positive: bool = False, *, what: str | None = None) -> float:
        """A finite number (positive, or within [lo, hi], where asked)."""
        v = self.raw(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.err(key, what or "a finite number", v)
        if positive and v <= 0:
            raise self.err(key, what or "positive", v)
        if lo is not None and v < lo or hi is not None and v > hi:
            raise self.err(key, what or f"within [{lo}, {hi}]", v)
        return float(v)

    def whole(self, key: str, lo: int) -> int:
        """A whole number >= lo."""
        v = self.raw(key)
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise self.err(key, f"a whole number >= {lo}", v)
        return v

    def text(self, key: str) -> str:
        """A non-empty string."""
        v = self.raw(key)
        if not isinstance(v, str) or not v:
            raise self.err(key, "a non-empty string", v)
        return v

    def texts(self, key: str) -> tuple[str, ...]:
        """A non-empty list of non-empty strings."""
        v = self.raw(key)
        if not isinstance(v, list) or not v or not all(isinstance(s, str) and s for s in v):
            raise self.err(key, "a non-empty list of strings", v)
        return tuple(v)

    def nums(self, key: str, n: int | None = None, *, what: str | None = None
             ) -> NDArray[np.float64]:
        """A non-empty list of finite numbers (of length n, where given)."""
        v = self.raw(key)
        ok = isinstance(v, list) and all(isinstance(x, (int, float)) and
                                         not isinstance(x, bool) and math.isfinite(x)
                                         for x in v)
        if not ok or (n is not None and len(v) != n) or not v:
            raise self.err(key, what or f"a list of {n or 'some'} finite numbers", v)
        return np.asarray(v, dtype=np.float64)

    def vec3(self, key: str) -> tuple[float, float, float]:
        """Three finite numbers [x, y, z]."""
        x, y, z = self.nums(key, 3, what="3 finite numbers [x, y, z]")
        return float(x), float(y), float(z)

    def flag(self, key: str) -> bool:
        """true or false."""
        v = self.raw(key)
        if not isinstance(v, bool):
            raise self.err(key, "true or false", v)
        return v

    def sub(self, key: str, valid: Sequence[str] | None = None, *,
            required: bool = False) -> SpecTable:
        """The sub-table ``key``, its keys checked against ``valid`` (default: the
        schema's entry for it)."""
        v = self.raw(key)
        if not isinstance(v, dict):
            raise self.err(key, "a table", v)
        return SpecTable(v, self.file, self.where(key), self.error, self.kind,
                         valid=valid, required=required, schema=self._schema)

    def either(self, one: str, other: Sequence[str]) -> bool:
        """True if the table uses ``one``, False if it uses every key of ``other``;
        an error if it mixes them (the unused ones would be silently ignored)."""
        mixed = [k for k in other if k in self.data]
        if one in self.data and mixed:
            raise self.error(f"Expected either `{self.where(one)}` or "
                             f"{' + '.join(f'`{self.where(k)}`' for k in other)} in "
                             f"{self.file}, got both; remove one.")
        return one in self.data


class Catalogue(Generic[T]):
    """The shipped descriptions of one kind (every ``*.toml`` of a folder) by name,
    and the loading of a name or a user's file.

    Parameters
    ----------
    folder : Path
        Where the shipped files are.
    load : callable
        Reads one file into its dataclass (which has a ``name``).
    error : type of TunnelsimError
        The class raised.
    kind : str
        "sensor", "platform" ...: the words of the messages.
    """

    def __init__(self, folder: Path, load: Callable[[Path], T], error: ErrorType,
                 kind: str) -> None:
        self.folder, self._load, self.error, self.kind = folder, load, error, kind

    def registry(self) -> dict[str, str]:
        """{name: path} of the shipped files; an error for two files of one name."""
        out: dict[str, str] = {}
        for f in sorted(self.folder.glob("*.toml")):
            name = getattr(self._load(f), "name")  # noqa: B009 (T is any dataclass)
            if name in out:
                raise self.error(f"Expected unique {self.kind} names, got {name!r} in "
                                 f"both {Path(out[name]).name} and {f.name}.")
            out[name] = str(f)
        return out

    def names(self) -> list[str]:
        """The shipped names, sorted."""
        return sorted(self.registry())

    def load(self, name_or_path: str | os.PathLike[str]) -> T:
        """A shipped description by name, or a TOML file by path."""
        if not isinstance(name_or_path, (str, os.PathLike)):
            raise self.error(f"Expected a {self.kind} name or a path to a .toml file, got "
                             f"{type(name_or_path).__name__}; see list_{self.kind}s().")
        if not str(name_or_path).strip():
            raise self.error(f"Expected a {self.kind} name in {self.names()} or a .toml "
                             "path, got an empty string.")
        p = Path(name_or_path)
        if p.suffix == ".toml" or p.exists():
            if not p.is_file():
                raise self.error(f"Expected a {self.kind} TOML file, got '{p}' which does "
                                 "not exist.")
            return self._load(p)
        reg = self.registry()
        if str(name_or_path) not in reg:
            raise self.error(f"Expected a {self.kind} name in {sorted(reg)} or a .toml "
                             f"path, got {str(name_or_path)!r}.")
        return self._load(Path(reg[str(name_or_path)]))
