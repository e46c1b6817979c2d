"""The documentation as a newcomer meets it: every relative link and image in README.md,
CHANGELOG.md and docs/*.md leads to a file that exists (and a `#anchor` to a heading of it),
the README stays a five-minute read, the version that `twomem --version` prints is the newest
release of CHANGELOG.md (as CITATION.cff says), and no file of the repository reads like a
development diary: history belongs to the commit messages."""
from __future__ import annotations

import re
import subprocess

import pytest

from twomem_testlib import EXE, SOURCE

DOCS = [SOURCE / "README.md", SOURCE / "CHANGELOG.md", *sorted((SOURCE / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
IMAGE = re.compile(r"<img\s[^>]*src=\"([^\"]+)\"")
RELEASE = re.compile(r"^## \[(\d+\.\d+\.\d+)\]", re.M)


def prose(text: str) -> str:
    """The text without fenced code blocks and inline code, where brackets are not links."""
    text = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    return re.sub(r"`[^`\n]*`", "", text)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    heading = re.sub(r"[`*_]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", heading).replace(" ", "-")


def anchors(path) -> set[str]:
    text = re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M)
    return {slug(h) for h in re.findall(r"^#+\s+(.*)$", text, re.M)}


def targets(path):
    text = prose(path.read_text())
    yield from LINK.findall(text)
    yield from IMAGE.findall(text)


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(SOURCE)))
def test_relative_links_resolve(doc):
    assert doc.exists(), f"{doc} is missing"
    broken = []
    for target in targets(doc):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):   # http:, https:, mailto:
            continue
        name, _, anchor = target.partition("#")
        dest = (doc.parent / name).resolve() if name else doc
        if not dest.exists():
            broken.append(f"{target}: no file {dest}")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(f"{target}: no heading #{anchor} in {dest.name}")
    assert not broken, f"{doc.name}: broken links:\n" + "\n".join(broken)


def test_readme_is_short():
    lines = (SOURCE / "README.md").read_text().count("\n")
    assert lines <= 300, f"README.md has {lines} lines; the manual belongs in docs/"


def newest_release() -> str:
    found = RELEASE.findall((SOURCE / "CHANGELOG.md").read_text())
    assert found, "CHANGELOG.md has no release heading '## [X.Y.Z] - date'"
    return found[0]


def test_version_is_the_newest_release():
    first = subprocess.run([EXE, "--version"], capture_output=True, text=True, check=True).stdout.splitlines()[0]
    assert first == f"twomem {newest_release()}", f"twomem --version says {first!r}"
    cff = re.search(r"^version:\s*\"?([^\"\s]+)", (SOURCE / "CITATION.cff").read_text(), re.M)
    assert cff and cff.group(1) == newest_release(), "CITATION.cff's version is not CHANGELOG.md's newest"


# spelled in pieces, so that this file does not match its own search
DIARY = re.compile("|".join([r"\bround" + r" [0-9]+", r"\bthis" + " round", r"\blast" + " round",
                             r"\brounds" + " ago", r"\bworking" + r" sessions?\b"]), re.I)


def test_no_development_diary():
    try:
        listed = subprocess.run(["git", "-C", str(SOURCE), "ls-files"], capture_output=True, text=True,
                                check=True).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: no list of the repository's files")
    hits = []
    for name in listed:
        path = SOURCE / name
        try:
            text = path.read_text()
        except (OSError, UnicodeDecodeError):
            continue          # binary files (figures, reference results), removed files
        for number, line in enumerate(text.splitlines(), 1):
            if DIARY.search(line):
                hits.append(f"{name}:{number}: {line.strip()[:100]}")
    assert not hits, "history belongs in commit messages, not in files:\n" + "\n".join(hits)
