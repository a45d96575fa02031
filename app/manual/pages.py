"""The manual as the app serves it at /help: the Markdown of ``docs/`` with the markdown
extensions and the nav of ``mkdocs.yml``, rendered in the app's own page (nothing from the
network). A page ``guides/reviewing.md`` is ``/help/guides/reviewing``; an ``index.md`` is its
folder's URL."""

from __future__ import annotations

import posixpath
import re
from dataclasses import dataclass
from functools import cache
from pathlib import PurePosixPath
from typing import Any

from app.core.errors import NotFoundError
from app.manual.reference import DOCS, REPO, Schema, expand

PREFIX = "/help"
IMAGE_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}
LINK = re.compile(r'(href|src)="([^"]*)"')


@dataclass(frozen=True)
class NavItem:
    title: str
    url: str | None  # None for a section
    children: tuple[NavItem, ...] = ()


@dataclass(frozen=True)
class Page:
    title: str
    html: str
    toc: str
    source: str  # the Markdown file, relative to docs/


@cache
def mkdocs_config() -> dict[str, Any]:
    """mkdocs.yml (plain YAML: no Python tags)."""
    import yaml

    loaded: dict[str, Any] = yaml.safe_load((REPO / "mkdocs.yml").read_text())
    return loaded


def url_of(source: str) -> str:
    """The /help URL of a docs file (``guides/reviewing.md`` → ``/help/guides/reviewing``)."""
    path = PurePosixPath(source)
    if path.name == "index.md":
        parent = str(path.parent)
        return f"{PREFIX}/" if parent == "." else f"{PREFIX}/{parent}/"
    return f"{PREFIX}/{path.with_suffix('')}"


def _nav_items(entries: list[Any]) -> tuple[NavItem, ...]:
    items = []
    for entry in entries:
        ((title, target),) = entry.items()
        if isinstance(target, list):
            items.append(NavItem(title, None, _nav_items(target)))
        else:
            items.append(NavItem(title, url_of(target)))
    return tuple(items)


@cache
def nav() -> tuple[NavItem, ...]:
    """The manual's navigation, as mkdocs.yml gives it."""
    return _nav_items(mkdocs_config()["nav"])


def _extensions() -> tuple[list[str], dict[str, dict[str, Any]]]:
    names, configs = [], {}
    for entry in mkdocs_config().get("markdown_extensions", []):
        if isinstance(entry, dict):
            ((name, config),) = entry.items()
            configs[name] = dict(config or {})
        else:
            name = entry
        names.append(name)
    # An align attribute, not a style one: the pages' CSP allows no inline style.
    configs.setdefault("tables", {})["use_align_attribute"] = True
    if "tables" not in names:
        names.append("tables")
    return names, configs


def source_of(path: str) -> str:
    """The docs file behind a /help path ('' → index.md); NotFoundError when none is."""
    clean = path.strip("/")
    candidates = [f"{clean}/index.md", f"{clean}.md"] if clean else ["index.md"]
    for candidate in candidates:
        file = (DOCS / candidate).resolve()
        if file.is_relative_to(DOCS) and file.is_file():
            return candidate
    raise NotFoundError(f"The manual has no page {PREFIX}/{clean}; its contents are at {PREFIX}/.")


def _rewrite_links(html: str, source: str) -> str:
    """Relative links of a page made /help URLs: ``.md`` pages to their page, files (pictures)
    to /help/<their path under docs/>."""
    folder = posixpath.dirname(source)

    def replace(match: re.Match[str]) -> str:
        attribute, target = match.group(1), match.group(2)
        if not target or target.startswith(("#", "/", "mailto:")) or "://" in target:
            return match.group(0)
        path, _, anchor = target.partition("#")
        resolved = posixpath.normpath(posixpath.join(folder, path))
        url = url_of(resolved) if resolved.endswith(".md") else f"{PREFIX}/{resolved}"
        return f'{attribute}="{url}{"#" + anchor if anchor else ""}"'

    return LINK.sub(replace, html)


def render_page(path: str, schema: Schema) -> Page:
    """One page of the manual, its markers expanded from the code and its links made /help's."""
    import markdown

    source = source_of(path)
    text = expand((DOCS / source).read_text(), schema)
    names, configs = _extensions()
    converter = markdown.Markdown(extensions=names, extension_configs=configs)
    html = converter.convert(text)
    heading = re.search(r"^# (.+)$", text, re.M)
    title = heading.group(1).strip() if heading else "weldpool"
    toc_tokens = getattr(converter, "toc_tokens", [])
    toc = "".join(
        f'<li><a href="#{token["id"]}">{token["name"]}</a></li>'
        for top in toc_tokens
        for token in top.get("children", [])
    )
    return Page(title, _rewrite_links(html, source), toc, source)


def picture(path: str) -> tuple[bytes, str]:
    """A picture the manual shows (under docs/), with its media type; NotFoundError otherwise."""
    file = (DOCS / path.strip("/")).resolve()
    media = IMAGE_TYPES.get(file.suffix.lower())
    if media is None or not file.is_relative_to(DOCS) or not file.is_file():
        raise NotFoundError(f"The manual has no picture {PREFIX}/{path.strip('/')}.")
    return file.read_bytes(), media
