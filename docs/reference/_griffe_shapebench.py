"""A griffe extension that reads shapebench's docstrings the way its code writes them.

The docstrings use Google-style sections (``Args:``) with reStructuredText inline markup, and
attributes are documented by comments rather than docstrings. mkdocstrings (configured in
mkdocs.yml) loads this file; for every object it:

* documents an attribute without a docstring by its ``#:`` comment lines above it, or else by its
  trailing ``# comment`` (``# noqa``, ``# type:`` and ``# fmt:`` are not documentation);
* turns the reST roles (``:class:`~shapebench.api.types.Context```) into links to the object
  where the reference documents it, and into code where it does not;
* ends a paragraph introducing a literal block (``metadata::``) with one colon: the indented
  block under it is already a Markdown code block.
"""

from __future__ import annotations

import re
import tokenize
from functools import cache
from pathlib import Path

import griffe

_ROLE = re.compile(r":(?:class|meth|func|mod|data|attr|exc|obj):`(~?)([^`]+)`")
_NOT_DOCS = ("noqa", "type:", "fmt:", "pragma")


@cache
def _lines(path: str) -> list[str]:
    return Path(path).read_text().splitlines()


@cache
def _trailing(path: str) -> dict[int, str]:
    """Line number -> the comment that ends that line of code (not a comment line)."""
    with open(path, encoding="utf-8") as f:
        tokens = list(tokenize.generate_tokens(f.readline))
    return {
        tok.start[0]: tok.string.lstrip("#").strip()
        for tok in tokens
        if tok.type == tokenize.COMMENT and not tok.line.lstrip().startswith("#")
    }


def _comment(attr: griffe.Attribute) -> str | None:
    if attr.lineno is None or not isinstance(attr.filepath, Path):
        return None
    lines = _lines(str(attr.filepath))
    above, i = [], attr.lineno - 2
    while i >= 0 and lines[i].strip().startswith("#:"):
        above.insert(0, lines[i].strip()[2:].strip())
        i -= 1
    if above:
        return "\n".join(above)
    # a trailing comment on the assignment: `NAME = value  # what it is`
    trailing = _trailing(str(attr.filepath))
    for lineno in (attr.lineno, attr.endlineno):
        text = trailing.get(lineno or 0, "")
        if text and not text.startswith(_NOT_DOCS):
            return text
    return None


def _link(obj: griffe.Object, tilde: str, name: str) -> str:
    name = name.rstrip("()")
    short = name.rsplit(".", 1)[-1] if tilde else name
    identifier = name
    if "." not in name or not name.startswith("shapebench"):
        # a name as the module sees it: `Method`, `Dataset.load`
        head, _, rest = name.partition(".")
        module = obj if isinstance(obj, griffe.Module) else obj.module
        member = module.members.get(head)
        if member is not None:
            base = member.target_path if isinstance(member, griffe.Alias) else member.path
            identifier = base + (f".{rest}" if rest else "")
    # `optional`: a name the reference does not document (a module below the API) stays code
    return f'<autoref identifier="{identifier}" optional><code>{short}</code></autoref>'


def _markdown(obj: griffe.Object, text: str) -> str:
    text = _ROLE.sub(lambda m: _link(obj, m.group(1), m.group(2)), text)
    text = re.sub(r"(?m)^(\s*)::\s*$", "", text)
    return re.sub(r"(?m)(\S)::\s*$", r"\1:", text)


class ShapebenchDocstrings(griffe.Extension):
    def on_object(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.is_alias:
            return
        if isinstance(obj, griffe.Attribute) and obj.docstring is None:
            comment = _comment(obj)
            if comment:
                obj.docstring = griffe.Docstring(
                    comment, lineno=obj.lineno, endlineno=obj.lineno, parent=obj
                )
        if obj.docstring is not None:
            obj.docstring.value = _markdown(obj, obj.docstring.value)
