"""Every document the code and the docs cite is in the repository, and so is every numbered section
they cite: a reader following a citation finds what it points at.

What is scanned: the ``.py`` files of simple_message, robot_server, client, tests, bench and
examples, the Markdown pages under docs/ (docs/reference/ included), README.md and CONTRIBUTING.md.

What counts as a citation:

* **a document**: a name ending in ``.md``. With a folder (``docs/emulator.md``,
  ``tests/data/README.md``, ``../README.md`` in a page) it is looked for from the repository's root
  and from the citing file's folder; if neither has it, it is a citation of this repository only
  when its first folder is one the repository has (an upstream project's ``cpp/notes.md`` is not).
  A bare name (``README.md``, ``demo.md``) is looked for next to the citing file, at the root and
  in docs/. A web address is not a citation of this repository.
* **a section**: such a name followed by ``§`` and a number (``docs/reference/protocol.md §8.1``;
  backquotes, a line break or a comment's ``#`` may come between). The number must be a heading of
  that document (``### 8.1 ...``).
* **a bare mark**: a ``§`` and a number with no name before it. In a page of docs/reference/ it
  means that page. Elsewhere it means docs/reference/protocol.md (simple_message/__init__.py says
  so for its package, and robot_server, client, tests, bench and the README use bare marks the
  same way: framing, replies, MotoROS), except when it continues a citation of a motion document
  (``docs/reference/motion.md §3.3, §3.5``; the last section citation before it in the file
  decides): then it means docs/reference/motion.md.

Every broken citation is listed in one failure, as ``file:line: citation: what is missing``.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
REFERENCE = ROOT / "docs" / "reference"
#: the document a bare mark means, unless it continues a citation named in _CONTINUED
DEFAULT_REFERENCE = ROOT / "docs/reference/protocol.md"
#: a bare mark after a section citation of a document with this stem means this reference
_CONTINUED = {"motion": ROOT / "docs/reference/motion.md"}

#: functions whose text quotes citations as examples, broken on purpose: not citations
_QUOTED = {
    "tests/test_rs_model_file.py": "test_the_citation_check_finds_what_the_repository_does_not_have",
    "tests/test_citations.py": "test_the_rules_on_examples",
}

_MARK = "\u00a7"
_URL = re.compile(r"(?:https?://|\b[\w-]+(?:\.[\w-]+)+/)\S*")
_NAME = re.compile(r"(?<![\w./{}-])((?:\.\.?/)*(?:[\w-]+/)*[\w.-]*[\w-]\.md)(?![\w-])")
_AFTER_NAME = re.compile(rf"`*[\s#]*{_MARK} ?(\d+(?:\.\d+)*)")
_SECTION = re.compile(rf"{_MARK} ?(\d+(?:\.\d+)*)")
_HEADING = re.compile(r"^#{1,6}[ \t]+(\d+(?:\.\d+)*)\.?[ \t]", re.MULTILINE)


@dataclass(frozen=True)
class Citation:
    """One citation: where it is, what it names (``None`` for a bare mark) and which section."""

    where: str  # the citing file, from the root
    line: int
    name: str | None
    section: str | None
    document: Path | None  # the file it resolves to, None when there is none

    def __str__(self) -> str:
        cited = " ".join(p for p in (self.name, self.section and _MARK + self.section) if p)
        return f"{self.where}:{self.line}: {cited}"

    @property
    def kind(self) -> str:
        return "bare mark" if self.name is None else "document" if self.section is None else "section"


def scanned_files() -> list[Path]:
    packages = ("simple_message", "robot_server", "client", "tests", "bench", "examples")
    code = [path for package in packages for path in sorted((ROOT / package).rglob("*.py"))]
    return code + sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md", ROOT / "CONTRIBUTING.md"]


def _is_ours(name: str, citing: Path) -> bool:
    """Whether ``name`` cites a file of this repository: a bare or relative name always, a path
    only when its first folder is one the repository has (at the root or beside the citing file)."""
    if "/" not in name or name.startswith("."):
        return True
    first = name.split("/", 1)[0]
    return any((base / first).is_dir() for base in (ROOT, citing.parent))


def _resolve(name: str, citing: Path) -> Path | None:
    """The file ``name`` means, cited from ``citing``; None if there is none."""
    if name.startswith("."):
        candidates = [citing.parent / name]
    elif "/" in name:
        candidates = [ROOT / name, citing.parent / name]
    else:
        candidates = [citing.parent / name, ROOT / name, ROOT / "docs" / name]
    return next((candidate.resolve() for candidate in candidates if candidate.is_file()), None)


def _quoted_lines(path: Path, text: str) -> range:
    """The lines of the function of ``path`` that _QUOTED names (none if it names none)."""
    function = _QUOTED.get(path.relative_to(ROOT).as_posix())
    for node in ast.walk(ast.parse(text)) if function else ():
        if isinstance(node, ast.FunctionDef) and node.name == function and node.end_lineno is not None:
            return range(node.lineno, node.end_lineno + 1)
    return range(0)


def citations_in(text: str, citing: Path) -> Iterator[Citation]:
    """The citations of ``text``, the contents of the file ``citing``, in the order they come."""
    where = citing.relative_to(ROOT).as_posix() if citing.is_relative_to(ROOT) else citing.name
    text = _URL.sub(lambda url: " " * len(url[0]), text)  # blanked, the offsets kept

    def line(offset: int) -> int:
        return text.count("\n", 0, offset) + 1

    found: list[tuple[int, Citation]] = []
    named_marks: list[range] = []  # where the marks of section citations are
    for match in _NAME.finditer(text):
        name = match[1]
        if not _is_ours(name, citing):
            continue
        after = _AFTER_NAME.match(text, match.end())
        if after is not None:
            named_marks.append(range(match.end(), after.end()))
        section = after[1] if after is not None else None
        found.append((match.start(), Citation(where, line(match.start()), name, section, _resolve(name, citing))))
    for mark in _SECTION.finditer(text):
        if any(mark.start() in span for span in named_marks):
            continue
        if citing.suffix == ".md" and citing.parent == REFERENCE:
            document = citing  # a reference page's own sections
        else:
            before = [(o, c.name) for o, c in found if o < mark.start() and c.name and c.section]
            stem = Path(max(before)[1]).stem if before else ""
            document = _CONTINUED.get(stem, DEFAULT_REFERENCE)
        bare = Citation(where, line(mark.start()), None, mark[1], document if document.is_file() else None)
        found.append((mark.start(), bare))
    yield from (citation for _, citation in sorted(found, key=lambda pair: pair[0]))


@cache
def sections_of(document: Path) -> frozenset[str]:
    """The section numbers of ``document``'s numbered headings."""
    return frozenset(_HEADING.findall(document.read_text(encoding="utf-8")))


def problem(citation: Citation) -> str | None:
    """What is missing for ``citation``, or None."""
    if citation.document is None:
        missing = citation.name if citation.name is not None else "the reference"
        return f"no document {missing} in the repository"
    if citation.section is not None and citation.section not in sections_of(citation.document):
        return f"no section {citation.section} in {citation.document.relative_to(ROOT).as_posix()}"
    return None


def broken_citations() -> list[tuple[Citation, str]]:
    broken = []
    for path in scanned_files():
        text = path.read_text(encoding="utf-8")
        quoted = _quoted_lines(path, text) if path.suffix == ".py" else range(0)
        for citation in citations_in(text, path):
            why = problem(citation)
            if why is not None and citation.line not in quoted:
                broken.append((citation, why))
    return broken


def test_every_cited_document_and_section_is_in_the_repository() -> None:
    broken = broken_citations()
    assert not broken, f"{len(broken)} citations point at nothing in the repository:\n" + "\n".join(
        f"{citation}: {why}" for citation, why in broken
    )


def test_the_rules_on_examples() -> None:
    here = ROOT / "robot_server" / "control" / "example.py"
    text = (
        "cited: docs/reference/protocol.md §8.1 and ``docs/reference/motion.md`` §4, §12\n"
        "gone: simple-message.md §3, §4 and docs/motion.md\n"
        "the cubic (motion.md §3.3, §3.5) and the reply (docs/reference/protocol.md §10 pitfall 5)\n"
        "bare: §1.2 and §99; wrapped: docs/reference/motion.md\n"
        "# §3.2 in a comment\n"
        "elsewhere: https://github.com/x/y/blob/main/notes.md, upstream cpp/notes.md, README.md\n"
    )
    found = [(str(c).split(": ", 1)[1], c.kind, problem(c)) for c in citations_in(text, here)]
    assert found == [
        ("docs/reference/protocol.md §8.1", "section", None),
        ("docs/reference/motion.md §4", "section", None),
        ("§12", "bare mark", "no section 12 in docs/reference/motion.md"),  # continues the motion citation
        ("simple-message.md §3", "section", "no document simple-message.md in the repository"),
        ("§4", "bare mark", None),  # the protocol reference's §4
        ("docs/motion.md", "document", "no document docs/motion.md in the repository"),
        ("motion.md §3.3", "section", "no document motion.md in the repository"),
        ("§3.5", "bare mark", None),
        ("docs/reference/protocol.md §10", "section", None),
        ("§1.2", "bare mark", None),
        ("§99", "bare mark", "no section 99 in docs/reference/protocol.md"),
        ("docs/reference/motion.md §3.2", "section", None),
        ("README.md", "document", None),
    ]
