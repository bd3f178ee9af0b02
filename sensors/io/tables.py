"""Text tables as surveyors' software writes them: the dialect (encoding, delimiter,
decimal mark, header row) is sniffed, the columns are found by their names (aliases in
English and German) or by a user mapping (``--columns``).

The readers of control points (``survey.adjust.controlpoints``) and of other point or
pose tables use this one module, so that every table a user hands over is read by the
same rules and fails with the same kind of message: what was found (encoding,
delimiter, decimal mark, header) and which column could not be mapped.

Rules (each a ``# DECISION:`` below):

- encoding: UTF-8 (a byte-order mark is dropped), UTF-16 with a byte-order mark (Excel's
  "Unicode text"), else Windows-1252 (the superset of Latin-1's printable characters
  that office software writes), else Latin-1; ``Dialect.encoding`` says which was used;
- delimiter: tab, ``;``, ``|``, ``,`` or runs of white space, whichever splits every data
  line into the same number (>= 2) of fields, most of them numbers;
- decimal comma: only with a delimiter that is not a comma, when numbers are written
  ``1234,56`` (a ``.`` thousands separator, ``1.234,56``, is then dropped);
- header: the first row is a header when two of its fields are not numbers in columns
  that hold numbers on every other line, or it is all text above such a column (so
  ids, text or numbers, decide nothing);
- lines starting with ``#`` and blank lines are skipped (``# crs: EPSG:2056``).
"""

from __future__ import annotations

import csv
import re
import unicodedata
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from sensors.io.errors import TableFileError

__all__ = ["DELIMITER_NAMES", "Dialect", "Table", "decode_text",
           "map_columns", "normalise_name", "numeric_columns", "parse_columns",
           "read_table", "sniff", "to_float"]


#: Delimiters tried, in order of preference when several split the lines alike.
#: "ws" stands for runs of white space (spaces and tabs).
DELIMITERS = ("\t", ";", "|", ",", "ws")
#: How messages name each delimiter.
DELIMITER_NAMES = {"\t": "tab", ";": "semicolon ';'", "|": "bar '|'", ",": "comma ','",
                   "ws": "white space"}
#: Encodings tried after UTF-8; cp1252 decodes all but 5 bytes, Latin-1 every byte.
FALLBACK_ENCODINGS = ("cp1252", "latin-1")

_NUM = re.compile(r"^[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?$")
_NUM_COMMA = re.compile(r"^[+-]?(?:\d+,?\d*|,\d+)(?:[eE][+-]?\d+)?$")
_THOUSANDS_DOT = re.compile(r"^[+-]?\d{1,3}(?:\.\d{3})+(?:,\d*)?(?:[eE][+-]?\d+)?$")
_UNIT = re.compile(r"\s*[\[(][^\])]*[\])]\s*$")


@dataclass(frozen=True)
class Dialect:
    """How a table file is written.

    Attributes
    ----------
    encoding : str, the codec used to decode it ("utf-8", "utf-8-sig", "utf-16",
        "cp1252" or "latin-1")
    delimiter : str, one of ``DELIMITERS`` ("ws": runs of white space)
    decimal : "." or ","
    header : bool, the first row names the columns
    """

    encoding: str
    delimiter: str
    decimal: str
    header: bool

    def describe(self) -> str:
        """The dialect in words, for messages and reports."""
        enc = {"utf-8-sig": "UTF-8 with BOM", "utf-8": "UTF-8", "utf-16": "UTF-16",
               "cp1252": "Windows-1252/Latin-1", "latin-1": "Latin-1"}.get(
            self.encoding, self.encoding)
        return (f"{DELIMITER_NAMES[self.delimiter]} delimiter, decimal "
                f"{'comma' if self.decimal == ',' else 'point'}, {enc}, "
                f"{'a header row' if self.header else 'no header row'}")


@dataclass
class Table:
    """A table read as text: ``names`` (the header's fields, or None), ``rows`` (lists
    of str, the data rows) and ``lines`` (each row's line number in the file, from 1)."""

    path: Path
    dialect: Dialect
    names: list[str] | None
    rows: list[list[str]]
    lines: list[int]

    def number(self, text: str) -> float:
        """One field as a float in this table's decimal mark (ValueError if none)."""
        return to_float(text, self.dialect.decimal)

    def is_number(self, text: str) -> bool:
        """Whether a field is a number in this table's decimal mark."""
        try:
            self.number(text)
        except ValueError:
            return False
        return True


def to_float(text: str, decimal: str) -> float:
    """A field as a float: ``decimal`` "," reads ``1.234,5`` and ``1234,5`` as 1234.5;
    "." reads Python's float syntax (no thousands separators). ValueError otherwise."""
    t = text.strip().strip('"').strip()
    if decimal == ",":
        if "." in t and not _THOUSANDS_DOT.match(t):
            raise ValueError(f"not a decimal-comma number: {text!r}")
        t = t.replace(".", "").replace(",", ".")
    elif "," in t:
        raise ValueError(f"not a number: {text!r}")
    # DECISION: only plain decimal numbers (no "nan", "inf", "1_000": Python's float
    # reads them, a survey table never means them).
    if not _NUM.match(t):
        raise ValueError(f"not a number: {text!r}")
    return float(t)


def decode_text(data: bytes) -> tuple[str, str]:
    """(text, encoding) of a file's bytes (see the module doc for the order tried)."""
    if data.startswith(b"\xef\xbb\xbf"):
        return data.decode("utf-8-sig"), "utf-8-sig"
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        return data.decode("utf-16"), "utf-16"
    try:
        return data.decode("utf-8"), "utf-8"
    except UnicodeDecodeError:
        pass
    # DECISION: not UTF-8 means an office or instrument export in a Windows code page:
    # cp1252 first (it has the Euro sign and typographic quotes where Latin-1 has
    # control codes), Latin-1 for the five bytes cp1252 leaves undefined.
    for enc in FALLBACK_ENCODINGS:
        try:
            return data.decode(enc), enc
        except UnicodeDecodeError:
            continue
    raise AssertionError("Latin-1 decodes every byte")  # pragma: no cover


def _split(line: str, delim: str) -> list[str]:
    if delim == "ws":
        return line.split()
    return [f.strip() for f in next(csv.reader([line], delimiter=delim))]


def _numeric(field: str, decimal: str) -> bool:
    try:
        to_float(field, decimal)
    except ValueError:
        return False
    return True


def _decimal_of(rows: list[list[str]]) -> str:
    """"," when some field is written with a decimal comma and none with a point."""
    comma = point = 0
    for r in rows:
        for f in r:
            f = f.strip().strip('"')
            if _NUM_COMMA.match(f) and "," in f:
                comma += 1
            elif _NUM.match(f) and "." in f:
                point += 1
    return "," if comma and not point else "."


def sniff(lines: Sequence[str]) -> tuple[str, str, bool]:
    """(delimiter, decimal, header) of a table's lines (comments and blanks removed).

    DECISION: a delimiter is a candidate when it splits every line into the same number
    (>= 2) of fields, one trailing empty field allowed; among candidates the one giving
    the most numeric data fields wins, ties in the order of ``DELIMITERS`` (so a comma
    beats the white space after it in ``id, x, y, z``). A comma delimiter forces a
    decimal point.
    """
    best: tuple[int, int, str, str] | None = None
    sample = list(lines[:200])
    for rank, d in enumerate(DELIMITERS):
        rows = [_split(ln, d) for ln in sample]
        counts = {len(r) for r in rows}
        if len(counts) != 1 or min(counts) < 2:
            continue
        dec = "." if d == "," else _decimal_of(rows[1:] or rows)
        data = rows[1:] if len(rows) > 1 else rows
        score = sum(_numeric(f, dec) for r in data for f in r)
        key = (score, -rank)
        if best is None or key > best[:2]:
            best = (score, -rank, d, dec)
    if best is None:
        raise ValueError("no delimiter splits every line into the same number of fields")
    _, _, delim, dec = best
    rows = [_split(ln, delim) for ln in sample[:50]]
    if len(rows) == 1:
        header = not any(_numeric(f, dec) for f in rows[0])
    else:
        # A header: text in columns that are numeric on every other sampled line.
        # DECISION: two such columns, or a first row of text only: one alone may be a
        # column of ids that happens to hold "A" above "1", "2" (hypothesis found a
        # headerless "A,0,0,0 / 0,1,1,1" read as a header); a real header names the
        # coordinate columns too.
        above = sum(not _numeric(rows[0][j], dec) and
                    all(_numeric(r[j], dec) for r in rows[1:])
                    for j in range(len(rows[0])))
        header = above >= 2 or (above >= 1 and
                                not any(_numeric(f, dec) for f in rows[0]))
    return delim, dec, header


def read_table(path: str | Path, *, what: str = "table",
               error: type[Exception] = TableFileError, hash_header: bool = False) -> Table:
    """Read a delimited text table, sniffing its dialect.

    Parameters
    ----------
    path : str or Path
    what : str
        What the file is, for messages ("control-point file").
    error : exception class
        Raised for an unreadable file (the caller's package error).
    hash_header : bool
        A '#' line before the first data line that holds a ',', ';', tab or '|' is
        the header, not a comment (EuRoC writes ``#timestamp,p_RS_R_x,...``).

    Returns
    -------
    Table
    """
    path = Path(path)
    if not path.is_file():
        raise error(f"Expected a {what}, got '{path}' which does not exist.")
    text, enc = decode_text(path.read_bytes())
    body: list[str] = []
    numbers: list[int] = []
    for k, ln in enumerate(text.splitlines(), start=1):
        if not ln.strip():
            continue
        if ln.lstrip().startswith("#") and not (
                hash_header and not body and any(d in ln for d in ",;\t|")):
            continue
        body.append(ln)
        numbers.append(k)
    if not body:
        raise error(f"Expected rows in the {what} '{path}', got none (encoding {enc}).")
    if any("\x00" in ln for ln in body[:200]):
        raise error(f"Expected a text table in the {what} '{path}', got binary data (NUL "
                    f"bytes; decoded as {enc}); export it as CSV or text.")
    try:
        delim, dec, header = sniff(body)
    except (ValueError, csv.Error):
        widths = {d: sorted({len(_split(ln, d)) for ln in body[:200]})
                  for d in DELIMITERS}
        seen = "; ".join(f"{DELIMITER_NAMES[d]}: {w[:4]} fields"
                         for d, w in widths.items())
        raise error(f"Expected a table with the same number of fields on every line in "
                    f"'{path}' (tab, ';', '|', ',' or white space between them), got "
                    f"lines of different widths with every delimiter ({seen}; encoding "
                    f"{enc}); make every line the same width.") from None
    try:
        rows = [_split(ln, delim) for ln in body]
    except csv.Error as exc:
        raise error(f"Expected delimited text in the {what} '{path}', got a line the "
                    f"{DELIMITER_NAMES[delim]} split cannot read ({exc}).") from None
    if len({len(r) for r in rows}) != 1:
        sizes = sorted({len(r) for r in rows})
        k = next(n for n, r in zip(numbers, rows) if len(r) != len(rows[0]))
        raise error(f"Expected {len(rows[0])} fields on every line of the {what} "
                    f"'{path}' ({DELIMITER_NAMES[delim]} delimiter, as its first lines), "
                    f"got lines of {sizes} fields (first at line {k}); make every line "
                    "the same width.")
    # A trailing delimiter gives an empty last field on every line: drop it.
    if all(r and r[-1] == "" for r in rows):
        rows = [r[:-1] for r in rows]
    names = rows[0] if header else None
    data, lines = (rows[1:], numbers[1:]) if header else (rows, numbers)
    return Table(path, Dialect(enc, delim, dec, header), names, data, lines)


def normalise_name(name: str) -> str:
    """A header name for matching: NFC, lower case, a unit in brackets and quotes
    dropped, inner white space, '-' and '_' removed ("Höhe [m]" -> "höhe",
    "Point_ID" -> "pointid")."""
    n = unicodedata.normalize("NFC", name).strip().strip('"\'').strip().lstrip("#")
    n = _UNIT.sub("", n).strip().lower()
    return re.sub(r"[\s_\-.]+", "", n)


def parse_columns(text: str, order: Sequence[str], *, flag: str = "--columns"
                  ) -> dict[str, str]:
    """A ``--columns`` value as {field: column}: either positional (``1,3,2,4`` or
    ``Punkt,Y,X,Höhe``, the columns of ``order``'s fields in that order) or named
    (``id=Punkt,e=Y,n=X,h=Höhe``, fields in ``order`` or its aliases given by the
    caller). A column is a 1-based number or a header name."""
    items = [s.strip() for s in text.split(",")]
    if not text.strip() or any(not s for s in items):
        raise TableFileError(f"Expected {flag} as a comma list ({','.join(order)}), got "
                         f"{text!r}.")
    if all("=" in s for s in items):
        out = {}
        for s in items:
            k, v = (p.strip() for p in s.split("=", 1))
            if k.lower() not in order:
                raise TableFileError(f"Expected {flag} fields among {', '.join(order)}, got "
                                 f"{k!r}.")
            out[k.lower()] = v
        return out
    if any("=" in s for s in items):
        raise TableFileError(f"Expected {flag} either all positional or all field=column, "
                         f"got {text!r}.")
    if len(items) > len(order):
        raise TableFileError(f"Expected at most {len(order)} columns in {flag} "
                         f"({','.join(order)}), got {len(items)}: {text!r}.")
    return dict(zip(order, items))


def map_columns(table: Table, aliases: Mapping[str, Sequence[str]],
                required: Sequence[str], *, columns: Mapping[str, str] | None = None,
                headerless: Sequence[str] = (), what: str = "table",
                flag: str = "--columns", error: type[Exception] = TableFileError,
                labels: Mapping[str, str] | None = None, unknown: str = "ignore"
                ) -> dict[str, int]:
    """The column index of each field.

    Parameters
    ----------
    table : Table
    aliases : {field: names}
        The header names each field may go by (compared after ``normalise_name``).
    required : fields that must be found
    columns : {field: column}, optional
        The user's mapping (``parse_columns``): a 1-based column number or a header name;
        it wins over the aliases.
    headerless : fields in column order for a table without a header (and no mapping):
        the table must then have exactly that many columns.
    what, flag : for messages: what the file is, and the option giving the mapping
        ("": a reader without such an option; messages then ask for a header).
    error : exception class raised.
    labels : {field: name}, optional
        How messages and ``flag`` name a field (default: the field itself).
    unknown : "ignore" or "error"
        What a header name no alias knows does (without ``columns``): nothing (extra
        columns such as a point code are common), or an error naming it.

    Returns
    -------
    {field: column index from 0}
    """
    d = table.dialect
    width = len(table.rows[0]) if table.rows else len(table.names or [])
    found = f"found {d.describe()}"
    if table.names is not None:
        found += f" ({', '.join(repr(n) for n in table.names)})"
    found += f", {width} columns"
    out: dict[str, int] = {}
    if columns:
        normed = [normalise_name(n) for n in table.names] if table.names else []
        for field, col in columns.items():
            if col.isdigit():
                k = int(col) - 1
                if not 0 <= k < width:
                    raise error(f"Expected {flag} column numbers 1..{width} in "
                                f"'{table.path}', got {col} for {field}; {found}.")
            elif normalise_name(col) in normed:
                k = normed.index(normalise_name(col))
            else:
                raise error(f"Expected {flag} to name a column of '{table.path}', got "
                            f"{col!r} for {field} which is not in its header; {found}.")
            out[field] = k
    if table.names is None and not columns:
        if len(headerless) != width:
            raise error(f"Expected {len(headerless)} columns "
                        f"({','.join(headerless)}, in that order) in the headerless "
                        f"{what} '{table.path}', got {width}; {found}; add a header row"
                        + (f" or pass {flag} (e.g. {flag} "
                           f"{','.join(str(i + 1) for i in range(len(required)))})."
                           if flag else " naming the columns."))
        out = {f: i for i, f in enumerate(headerless)}
    elif table.names is not None:
        normed = [normalise_name(n) for n in table.names]
        for field, names in aliases.items():
            if field in out:
                continue
            hits = [i for i, n in enumerate(normed) if n in {normalise_name(a)
                                                            for a in names}]
            hits = [i for i in hits if i not in out.values()]
            if len(hits) > 1:
                raise error(f"Expected one column for {field} in '{table.path}', got "
                            f"{' and '.join(repr(table.names[i]) for i in hits)}; {found}; "
                            + (f"pass {flag} to say which." if flag
                               else "rename one of them."))
            if hits:
                out[field] = hits[0]
        known = {normalise_name(a) for names in aliases.values() for a in names}
        strange = [n for n, m in zip(table.names, normed) if m and m not in known]
        if unknown == "error" and strange:
            raise error(f"Expected only the columns {', '.join(aliases)} in the {what} "
                        f"'{table.path}', got unknown "
                        f"{', '.join(repr(n) for n in strange)}; {found}; rename or "
                        f"remove those columns" + (f", or pass {flag}." if flag else "."))
    missing = [(labels or {}).get(f, f) for f in required if f not in out]
    if missing:
        raise error(f"Expected a column for {', '.join(missing)} in the {what} "
                    f"'{table.path}', got none that maps ({found}); rename the header"
                    + (f" or pass {flag} (e.g. {flag} "
                       f"{','.join(str(i + 1) for i in range(len(required)))} or "
                       f"{','.join(f'{f}=NAME' for f in missing)})." if flag else "."))
    return out


def numeric_columns(table: Table, columns: Mapping[str, int], fields: Sequence[str], *,
                    what: str = "table", flag: str = "--columns",
                    error: type[Exception] = TableFileError) -> NDArray[np.float64]:
    """(n, len(fields)) float64: the columns ``columns[f]`` of ``fields`` as numbers in
    the table's decimal mark; a field that is not a number fails naming its column,
    line, the dialect found and ``flag``."""
    out = np.empty((len(table.rows), len(fields)), dtype=np.float64)
    for i, (r, k) in enumerate(zip(table.rows, table.lines)):
        for j, f in enumerate(fields):
            c = columns[f]
            try:
                out[i, j] = table.number(r[c])
            except ValueError:
                name = repr(table.names[c]) if table.names else f"column {c + 1}"
                raise error(f"Expected a number in {name} ({f}) on line {k} of the {what} "
                            f"'{table.path}', got {r[c]!r}; found "
                            f"{table.dialect.describe()}; fix the line"
                            + (f" or pass {flag}." if flag else ".")) from None
    return out
