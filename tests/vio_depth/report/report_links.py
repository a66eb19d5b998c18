"""Helpers for report tests: every link of a report page must be relative and resolve."""

import re
from pathlib import Path
from urllib.parse import unquote

_HTML_LINK = re.compile(r'(?:src|href)="([^"]*)"')
_HTML_ID = re.compile(r'id="([^"]*)"')
_MD_LINK = re.compile(r"\]\(([^)\s]*)\)")


def links(path: Path) -> list[str]:
    text = path.read_text(encoding="utf-8")
    return (_HTML_LINK if path.suffix == ".html" else _MD_LINK).findall(text)


def broken_links(path: Path) -> list[str]:
    """Links of ``path`` that are absolute, go to the network, or point to nothing."""
    text = path.read_text(encoding="utf-8")
    ids = set(_HTML_ID.findall(text))
    bad = []
    for link in links(path):
        if link.startswith("#"):
            if link[1:] not in ids:
                bad.append(link)
        elif "://" in link or link.startswith(("/", "//", "data:", "mailto:")) or ".." in Path(link).parts:
            bad.append(link)
        elif not (path.parent / unquote(link)).is_file():
            bad.append(link)
    return bad


def no_network(path: Path) -> bool:
    text = path.read_text(encoding="utf-8")
    return "http://" not in text and "https://" not in text and "<script" not in text
