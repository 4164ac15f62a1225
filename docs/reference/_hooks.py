"""The mkdocs hook that puts repository files outside docs/ into the site (mkdocs.yml `hooks:`).

Pages are written to be read on a repository browser too, so their relative links name files
anywhere in the checkout (``../shapebench/api/metric.py``, ``standard/README.md``). Every page
here knows where it lives in the repository, and each relative link is resolved from there:

* a file under docs/ is a page or a file of the site already: links to it are left to mkdocs;
* ``PAGES`` are repository Markdown files shown as pages of the site (the Results and Changes
  sections); links to them become links to those pages;
* any other file of the repository a page links to is copied into the site under ``repo/`` (and
  a Markdown one becomes a page, out of the navigation, whose own links are handled the same
  way), so the built site is complete and works offline;
* a link to nothing in the repository is left as written: ``mkdocs build --strict`` fails on it.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File, Files, InclusionLevel

#: Site page -> the repository Markdown file it shows.
PAGES = {"results.md": "leaderboards/README.md", "changes.md": "CHANGELOG.md"}
#: Where the site keeps the other repository files its pages link to.
REPO_DIR = "repo"

# [text](target "title") and [label]: target; the target ends at whitespace or ")"
_LINK = re.compile(r"(?m)(\]\(\s*<?)([^)\s>]+)|(^\s{0,3}\[[^\]]+\]:\s*<?)(\S+?)(?=>?(\s|$))")
_FENCE = re.compile(r"^\s*(```|~~~)")
_SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:|^//|^#|^/")


def _root(config) -> Path:
    return Path(config.config_file_path).resolve().parent


def _docs(config) -> Path:
    return Path(config.docs_dir).resolve()


def _segments(markdown: str):
    """(text, is_code) pieces: fenced code blocks are not scanned for links."""
    piece, fenced, out = [], None, []
    for line in markdown.splitlines(keepends=True):
        match = _FENCE.match(line)
        if match and (fenced is None or match.group(1) == fenced):
            if fenced is None:
                out.append(("".join(piece), False))
                piece, fenced = [line], match.group(1)
            else:
                piece.append(line)
                out.append(("".join(piece), True))
                piece, fenced = [], None
            continue
        piece.append(line)
    out.append(("".join(piece), fenced is not None))
    return out


def _targets(markdown: str):
    for text, code in _segments(markdown):
        if not code:
            for match in _LINK.finditer(text):
                yield match.group(2) or match.group(4)


def _source(file: File, config) -> Path:
    """Where a page's Markdown lives in the repository."""
    if file.src_uri in PAGES:
        return _root(config) / PAGES[file.src_uri]
    return Path(file.abs_src_path).resolve()


def _resolve(target: str, page_source: Path, config) -> tuple[Path, str] | None:
    """A relative link's repository file (a folder means its README.md) and its anchor."""
    if _SCHEME.match(target):
        return None
    path, _, anchor = target.partition("#")
    resolved = (page_source.parent / path).resolve()
    if resolved.is_dir() and (resolved / "README.md").is_file():
        resolved = resolved / "README.md"
    root = _root(config)
    if not resolved.is_file() or not resolved.is_relative_to(root):
        return None
    return resolved, anchor


def _site_uri(path: Path, config) -> str:
    """The site's src_uri for a repository file."""
    docs, root = _docs(config), _root(config)
    if path.is_relative_to(docs):
        return path.relative_to(docs).as_posix()
    rel = path.relative_to(root).as_posix()
    for page, source in PAGES.items():
        if source == rel:
            return page
    return f"{REPO_DIR}/{rel}"


def on_files(files: Files, config) -> Files:
    root = _root(config)
    for page, source in PAGES.items():
        files.append(File.generated(config, page, abs_src_path=str(root / source)))
    todo = list(files.documentation_pages())
    while todo:
        file = todo.pop()
        source = _source(file, config)
        for target in _targets(source.read_text(encoding="utf-8")):
            found = _resolve(target, source, config)
            if found is None or found[0].is_relative_to(_docs(config)):
                continue
            uri = _site_uri(found[0], config)
            if files.get_file_from_path(uri) is None:
                new = File.generated(config, uri, abs_src_path=str(found[0]))
                if new.is_documentation_page():
                    new.inclusion = InclusionLevel.NOT_IN_NAV
                    todo.append(new)
                files.append(new)
    return files


def on_page_markdown(markdown: str, page, config, files: Files) -> str:
    source = _source(page.file, config)
    here = posixpath.dirname(page.file.src_uri)
    inside = source.is_relative_to(_docs(config))

    def rewrite(match: re.Match) -> str:
        prefix, target = (match.group(1), match.group(2)) if match.group(2) else match.group(3, 4)
        found = _resolve(target, source, config)
        if found is None or (inside and found[0].is_relative_to(_docs(config))):
            return match.group(0)
        uri = posixpath.relpath(_site_uri(found[0], config), here or ".")
        return prefix + uri + (f"#{found[1]}" if found[1] else "")

    return "".join(text if code else _LINK.sub(rewrite, text) for text, code in _segments(markdown))
