"""Self-contained HTML from the Markdown the reports write, so that a client gets one
file that opens in any browser: figures are embedded as ``data:`` URIs, the style is
inline, nothing is fetched from elsewhere.

DECISION: a small converter for the subset the report writers use (headings, pipe
tables, ``-`` lists, paragraphs, images, inline code and bold) instead of a Markdown
package: no new dependency, and the HTML says exactly what the Markdown says because
it is made from it.
"""

from __future__ import annotations

import base64
import html
import os
import re
from collections.abc import Sequence
from pathlib import Path

from raytrace.fileio import atomic_writer

__all__ = ["MIME", "markdown_to_html", "write_report"]

#: Image types embedded, by suffix.
MIME = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg",
        ".svg": "image/svg+xml", ".gif": "image/gif"}
_IMAGE = re.compile(r"!\[([^\]]*)\]\(([^)\s]+)\)")
_LINK = re.compile(r"\[([^\]]+)\]\(([^)\s]+)\)")
_STYLE = ("body{font-family:sans-serif;max-width:60em;margin:2em auto;padding:0 1em;"
          "line-height:1.4}table{border-collapse:collapse;margin:0.5em 0}"
          "td,th{border:1px solid #999;padding:2px 6px}td.r,th.r{text-align:right}"
          "code{background:#eee;padding:0 2px;word-break:break-all}img{max-width:100%}")


def _data_uri(src: str, base: Path | None) -> str | None:
    """The image file ``src`` (relative to ``base``) as a data URI, None when missing
    or remote."""
    if re.match(r"^[a-z][a-z0-9+.-]*:", src, re.I):
        return None
    p = Path(src) if base is None else base / src
    mime = MIME.get(p.suffix.lower())
    if mime is None or not p.is_file():
        return None
    return f"data:{mime};base64,{base64.b64encode(p.read_bytes()).decode('ascii')}"


def _inline(text: str, base: Path | None) -> str:
    """Inline Markdown: images (embedded), links (text only), `code`, **bold**."""
    out, pos = [], 0
    for m in _IMAGE.finditer(text):
        out.append(_inline_plain(text[pos:m.start()]))
        uri = _data_uri(m.group(2), base)
        alt = html.escape(m.group(1))
        out.append(f'<img alt="{alt}" src="{uri}">' if uri else
                   f"<em>[figure {alt}: {html.escape(m.group(2))} not found]</em>")
        pos = m.end()
    out.append(_inline_plain(text[pos:]))
    return "".join(out)


def _inline_plain(text: str) -> str:
    # DECISION: links keep their text and show the target as text: a report must not
    # make the browser fetch anything.
    text = _LINK.sub(lambda m: f"{m.group(1)} ({m.group(2)})", text)
    parts = re.split(r"(`[^`]*`)", text)
    res = []
    for p in parts:
        if len(p) >= 2 and p.startswith("`") and p.endswith("`"):
            res.append(f"<code>{html.escape(p[1:-1])}</code>")
        else:
            e = html.escape(p)
            res.append(re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", e))
    return "".join(res)


def _cells(line: str) -> list[str]:
    s = line.strip()
    s = s[1:] if s.startswith("|") else s
    s = s[:-1] if s.endswith("|") and not s.endswith("\\|") else s
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", s)]


def markdown_to_html(text: str, *, base: str | Path | None = None,
                     title: str | None = None) -> str:
    """A complete HTML document of report Markdown.

    Parameters
    ----------
    text : str, the Markdown
    base : folder the image paths are relative to (the Markdown file's folder)
    title : the document title (default: the first heading)
    """
    basep = None if base is None else Path(base)
    lines = text.splitlines()
    body: list[str] = []
    para: list[str] = []
    i = 0

    def flush() -> None:
        if para:
            body.append("<p>" + "<br>\n".join(_inline(p, basep) for p in para) + "</p>")
            para.clear()

    while i < len(lines):
        ln = lines[i]
        s = ln.strip()
        m = re.match(r"^(#{1,6})\s+(.*)$", s)
        if not s:
            flush()
            i += 1
        elif m:
            flush()
            k = len(m.group(1))
            body.append(f"<h{k}>{_inline(m.group(2), basep)}</h{k}>")
            if title is None:
                title = m.group(2)
            i += 1
        elif s.startswith("|") and i + 1 < len(lines) and \
                re.match(r"^\|?\s*:?-{2,}:?\s*(\|\s*:?-{2,}:?\s*)*\|?$", lines[i + 1].strip()):
            flush()
            head = _cells(s)
            align = ["r" if c.endswith(":") and not c.startswith(":") else ""
                     for c in _cells(lines[i + 1])]
            cls = [f' class="{a}"' if a else "" for a in align]
            rows = ["<tr>" + "".join(f"<th{cls[j] if j < len(cls) else ''}>"
                                     f"{_inline(c, basep)}</th>"
                                     for j, c in enumerate(head)) + "</tr>"]
            i += 2
            while i < len(lines) and lines[i].strip().startswith("|"):
                rows.append("<tr>" + "".join(f"<td{cls[j] if j < len(cls) else ''}>"
                                             f"{_inline(c, basep)}</td>"
                                             for j, c in enumerate(_cells(lines[i])))
                            + "</tr>")
                i += 1
            body.append("<table>\n" + "\n".join(rows) + "\n</table>")
        elif re.match(r"^[-*]\s+", s):
            flush()
            items = []
            while i < len(lines) and re.match(r"^[-*]\s+", lines[i].strip()):
                item = re.sub(r"^[-*]\s+", "", lines[i].strip())
                items.append(f"<li>{_inline(item, basep)}</li>")
                i += 1
            body.append("<ul>\n" + "\n".join(items) + "\n</ul>")
        else:
            para.append(s)
            i += 1
    flush()
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            f"<title>{html.escape(title or 'tunnelsim report')}</title>\n"
            f"<style>{_STYLE}</style>\n</head>\n<body>\n" + "\n".join(body) +
            "\n</body>\n</html>\n")


def write_report(path: str | os.PathLike[str], text: str, *, title: str | None = None,
                 formats: Sequence[str] = ("md", "html")) -> tuple[Path, ...]:
    """Write the Markdown report ``path`` and the self-contained HTML beside it
    (``path`` with suffix ``.html``), both atomically; images the Markdown names are
    read from ``path``'s folder, so write the figures first.

    Parameters
    ----------
    path : path-like, the Markdown file
    text : str, the report's Markdown
    title : str, optional
        The HTML document's title (default: the first heading).
    formats : sequence of {"md", "html"}
        The files to write, in this order (default both).

    Returns
    -------
    tuple of Path
        The files written, in the order of ``formats``.
    """
    path = Path(path)
    html_path = path.with_suffix(".html")
    if html_path == path:
        html_path = path.with_name(path.name + ".html")
    written = []
    for fmt in formats:
        # UTF-8 whatever the locale: the reports hold σ, ö, °.
        if fmt == "md":
            with atomic_writer(path) as fh:
                fh.write(text.encode("utf-8"))
            written.append(path)
        elif fmt == "html":
            with atomic_writer(html_path) as fh:
                fh.write(markdown_to_html(text, base=path.parent, title=title)
                         .encode("utf-8"))
            written.append(html_path)
        else:
            raise ValueError(f"Expected formats from ('md', 'html'), got {fmt!r}.")
    return tuple(written)
