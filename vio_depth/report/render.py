"""Render report sections to one self-contained HTML page and its Markdown twin.

Sections are plain data (:class:`Section` with blocks :class:`Text`, :class:`Note`,
:class:`Image`, :class:`Table`, :class:`Code`, :class:`Strip`); both renderers walk the same
list, so the two files always say the same. Image sources are paths relative to the
report folder; the HTML has inline CSS and loads nothing from the network.
"""

from __future__ import annotations

import html
from dataclasses import dataclass, field


@dataclass
class Text:
    text: str


@dataclass
class Note:
    """A remark set apart (e.g. "this section was omitted because ...")."""

    text: str


@dataclass
class Image:
    src: str  # relative to the report folder
    alt: str
    caption: str = ""


@dataclass
class Table:
    header: list
    rows: list


@dataclass
class Code:
    text: str
    summary: str = ""  # HTML: collapsible block with this title


@dataclass
class Strip:
    """Columns of images side by side: ``columns`` = [(title, caption, [Image or None, ...])];
    row ``k`` of every column shows the kind ``row_labels[k]``."""

    row_labels: list
    columns: list


@dataclass
class Section:
    title: str
    anchor: str
    blocks: list = field(default_factory=list)


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;max-width:1000px;margin:1.5em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.15em;border-bottom:1px solid #ddd;padding-bottom:.2em;
margin-top:1.6em}
table{border-collapse:collapse;font-size:.88em;margin:.6em 0}td,th{border:1px solid #ccc;padding:.25em .5em;
text-align:left;vertical-align:top}th{background:#f3f3f3}
.note{background:#fff8e1;border-left:4px solid #f2b134;padding:.4em .7em;margin:.6em 0;font-size:.92em}
pre{background:#f6f6f6;padding:.6em;overflow-x:auto;font-size:.82em}
img{max-width:100%;height:auto}figure{margin:.6em 0}figcaption{font-size:.85em;color:#555}
.strip td{text-align:center}.strip img{width:300px}
nav{font-size:.9em}nav a{margin-right:.8em}
"""


def to_html(title: str, sections: list) -> str:
    """The report as one HTML page (inline CSS, relative image links, no scripts)."""
    out = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
           '<meta name="viewport" content="width=device-width, initial-scale=1">',
           f"<title>{html.escape(title)}</title>", f"<style>{_CSS}</style>", "</head>", "<body>",
           f"<h1>{html.escape(title)}</h1>",
           "<nav>" + "".join(f'<a href="#{s.anchor}">{html.escape(s.title)}</a>' for s in sections) + "</nav>"]
    for s in sections:
        out.append(f'<h2 id="{s.anchor}">{html.escape(s.title)}</h2>')
        out.extend(_html_block(b) for b in s.blocks)
    out += ["</body>", "</html>", ""]
    return "\n".join(out)


def _html_img(im: Image) -> str:
    return f'<img src="{html.escape(im.src)}" alt="{html.escape(im.alt)}">'


def _text(s: str) -> str:
    """Escape text content (quotes need no escaping outside attributes)."""
    return html.escape(s, quote=False)


def _html_block(b) -> str:
    e = _text
    if isinstance(b, Text):
        return f"<p>{e(b.text)}</p>"
    if isinstance(b, Note):
        return f'<p class="note">{e(b.text)}</p>'
    if isinstance(b, Image):
        cap = f"<figcaption>{e(b.caption)}</figcaption>" if b.caption else ""
        return f"<figure>{_html_img(b)}{cap}</figure>"
    if isinstance(b, Table):
        head = "".join(f"<th>{e(str(h))}</th>" for h in b.header)
        rows = "".join("<tr>" + "".join(f"<td>{e(str(c))}</td>" for c in r) + "</tr>" for r in b.rows)
        return f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>"
    if isinstance(b, Code):
        pre = f"<pre>{e(b.text)}</pre>"
        return f"<details><summary>{e(b.summary)}</summary>{pre}</details>" if b.summary else pre
    if isinstance(b, Strip):
        head = "<th></th>" + "".join(f"<th>{e(t)}<br><small>{e(c)}</small></th>" for t, c, _ in b.columns)
        rows = []
        for k, label in enumerate(b.row_labels):
            cells = "".join(f"<td>{_html_img(imgs[k]) if imgs[k] is not None else '—'}</td>" for _, _, imgs in b.columns)
            rows.append(f"<tr><th>{e(label)}</th>{cells}</tr>")
        return f'<table class="strip"><thead><tr>{head}</tr></thead><tbody>{"".join(rows)}</tbody></table>'
    raise TypeError(f"unknown block {type(b).__name__}")


def _md_cell(value) -> str:
    return str(value).replace("|", "\\|").replace("\n", " ")


def _md_table(header, rows) -> str:
    lines = ["| " + " | ".join(_md_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_md_cell(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _md_img(im: Image) -> str:
    return f"![{im.alt.replace(']', ')')}]({im.src})"


def to_markdown(title: str, sections: list) -> str:
    """The report as Markdown (GitHub flavour), same content and image links as :func:`to_html`."""
    out = [f"# {title}", ""]
    for s in sections:
        out += [f"## {s.title}", ""]
        for b in s.blocks:
            out += [_md_block(b), ""]
    return "\n".join(out)


def _md_block(b) -> str:
    if isinstance(b, Text):
        return b.text
    if isinstance(b, Note):
        return f"> **Note:** {b.text}"
    if isinstance(b, Image):
        return _md_img(b) + (f"\n\n*{b.caption}*" if b.caption else "")
    if isinstance(b, Table):
        return _md_table(b.header, b.rows)
    if isinstance(b, Code):
        fence = "```"
        return (f"{b.summary}:\n\n" if b.summary else "") + f"{fence}\n{b.text}\n{fence}"
    if isinstance(b, Strip):
        header = [""] + [f"{t} ({c})" for t, c, _ in b.columns]
        rows = [[label] + [_md_img(imgs[k]) if imgs[k] is not None else "—" for _, _, imgs in b.columns]
                for k, label in enumerate(b.row_labels)]
        return _md_table(header, rows)
    raise TypeError(f"unknown block {type(b).__name__}")
