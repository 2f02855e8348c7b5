"""Static HTML report pages: headings, notes, tables, pictures and links, one file with its
pictures beside it; either built from sections (`mgpusim advise`) or rendered from a Markdown
report (:func:`write_markdown_page`: a study's report.md).

A page is plain HTML and CSS (no script, nothing fetched from elsewhere), so it opens from a
file in any browser, offline, and a headless browser can check it: every picture it shows is a
file in the page's folder, referred to by a relative link. A table wider than the page scrolls
in its own box, so the page itself never does.
"""
from __future__ import annotations

import html
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import pandas as pd
from markdown_it import MarkdownIt
from markdown_it.token import Token

from mgpusim.io.writers import write_text

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; font-size: 0.85em; margin: 0.5em 0; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.5em; text-align: right; }
th { background: #f0f0f0; } td.text, th.text { text-align: left; }
img { max-width: 100%; border: 1px solid #ddd; }
div.wide { overflow-x: auto; max-width: 100%; }
p.verdict { font-size: 1.05em; background: #f6f6f0; border-left: 4px solid #888; padding: 0.5em 0.8em; }
body.md th, body.md td { text-align: left; } body.md td { white-space: nowrap; }
pre { overflow-x: auto; background: #f8f8f8; padding: 0.5em; font-size: 0.8em; }
.note { color: #555; font-size: 0.9em; } code { background: #f4f4f4; padding: 0 0.2em; }
"""


@dataclass
class Section:
    """A heading and what follows it, in order: paragraphs (`text`, escaped), then `tables`
    (a caption and a DataFrame), `images` (a file in the page's folder and its caption) and
    `links` (a relative file and its text)."""

    title: str
    text: list[str] = field(default_factory=list)
    tables: list[tuple[str, pd.DataFrame]] = field(default_factory=list)
    images: list[tuple[str, str]] = field(default_factory=list)
    links: list[tuple[str, str]] = field(default_factory=list)
    code: list[str] = field(default_factory=list)


def html_table(df: pd.DataFrame, digits: int = 3) -> str:
    """A DataFrame as an HTML table: numbers to `digits` decimals, text left-aligned, escaped."""
    head = "".join(f"<th class=\"{_align(df[c])}\">{html.escape(str(c))}</th>" for c in df.columns)
    rows = []
    for values in df.itertuples(index=False):
        cells = "".join(f"<td class=\"{_align(df[c])}\">{html.escape(_cell(v, digits))}</td>"
                        for c, v in zip(df.columns, values))
        rows.append(f"<tr>{cells}</tr>")
    return (f"<div class=\"wide\"><table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody>"
            "</table></div>")


def _align(col: pd.Series) -> str:
    return "num" if pd.api.types.is_numeric_dtype(col) and not pd.api.types.is_bool_dtype(col) else "text"


def _cell(value: object, digits: int) -> str:
    if value is None or (isinstance(value, float) and value != value) or value is pd.NA:
        return ""
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def page_html(title: str, sections: Sequence[Section], subtitle: str = "") -> str:
    """The whole page."""
    parts = ["<!DOCTYPE html>", "<html lang=\"en\"><head><meta charset=\"utf-8\">",
             f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>"]
    if subtitle:
        parts.append(f"<p class=\"note\">{html.escape(subtitle)}</p>")
    for s in sections:
        parts.append(f"<h2>{html.escape(s.title)}</h2>")
        parts += [f"<p>{html.escape(t)}</p>" for t in s.text]
        parts += [f"<pre><code>{html.escape(c)}</code></pre>" for c in s.code]
        for caption, df in s.tables:
            if caption:
                parts.append(f"<p class=\"note\">{html.escape(caption)}</p>")
            parts.append(html_table(df))
        for src, caption in s.images:
            parts.append(f"<figure><img src=\"{html.escape(_relative(src))}\" alt=\"{html.escape(caption)}\">"
                         f"<figcaption class=\"note\">{html.escape(caption)}</figcaption></figure>")
        if s.links:
            items = "".join(f"<li><a href=\"{html.escape(_relative(href))}\">{html.escape(text)}</a></li>"
                            for href, text in s.links)
            parts.append(f"<ul>{items}</ul>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def _relative(ref: str) -> str:
    """A link within the page's folder (forward slashes), refused if it leaves it."""
    path = Path(ref)
    if path.is_absolute() or ".." in path.parts:
        raise ValueError(f"a report links only files beside it, got {ref!r}")
    return path.as_posix()


def write_page(path: Path, title: str, sections: Sequence[Section], subtitle: str = "") -> Path:
    """The page written whole (its pictures are already beside it)."""
    return write_text(page_html(title, sections, subtitle), path)


def markdown_html(text: str) -> tuple[str, str]:
    """A Markdown report as (title, HTML body): CommonMark with tables (markdown-it-py), raw
    HTML in the text shown as text; the first heading is the title, the first paragraph after
    it gets the class `verdict` (`id="verdict"`), every table its own scroll box."""
    md = MarkdownIt("commonmark", {"html": False}).enable("table")
    md.add_render_rule("table_open", _table_open)
    md.add_render_rule("table_close", _table_close)
    tokens = md.parse(text)
    title = ""
    for i, tok in enumerate(tokens):
        if tok.type == "heading_open" and not title:
            title = tokens[i + 1].content
        if tok.type == "paragraph_open" and title:
            tok.attrSet("class", "verdict")
            tok.attrSet("id", "verdict")
            break
    for tok in tokens:  # every picture and link stays in the page's folder
        for child in tok.children or ():
            ref = child.attrGet("src") if child.type == "image" else child.attrGet("href")
            if isinstance(ref, str) and not ref.startswith(("http://", "https://")):
                _relative(ref)
    return title, md.renderer.render(tokens, md.options, {})


def _table_open(self: object, tokens: Sequence[Token], idx: int, options: object, env: object) -> str:
    return "<div class=\"wide\"><table>\n"


def _table_close(self: object, tokens: Sequence[Token], idx: int, options: object, env: object) -> str:
    return "</table></div>\n"


def write_markdown_page(path: Path, text: str) -> Path:
    """The page of a Markdown report, written whole (its pictures are already beside it)."""
    title, body = markdown_html(text)
    page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<meta name=\"viewport\" content=\"width=device-width\"><title>{html.escape(title)}</title>"
            f"<style>{_STYLE}</style></head><body class=\"md\">\n{body}</body></html>\n")
    return write_text(page, path)
