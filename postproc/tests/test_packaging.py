"""pyproject.toml declares the same minimum versions as requirements.txt: installed alone (pip
install ./postproc), the package must not accept an older library that the plots fail with."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SPEC = re.compile(r"^\s*([A-Za-z0-9_.-]+)\s*([<>=!~].*)?$")


def requirements() -> dict[str, str]:
    out = {}
    for line in (ROOT / "requirements.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            name, version = SPEC.match(line).groups()
            out[name.lower()] = (version or "").replace(" ", "")
    return out


def declared() -> dict[str, str]:
    text = (ROOT / "pyproject.toml").read_text()
    out = {}
    for key in ("dependencies", "test"):
        block = re.search(rf"^{key}\s*=\s*\[(.*?)\]", text, re.S | re.M)
        assert block, f"pyproject.toml has no {key} list"
        for item in re.findall(r'"([^"]+)"', block.group(1)):
            name, version = SPEC.match(item).groups()
            out[name.lower()] = (version or "").replace(" ", "")
    return out


def test_pyproject_matches_requirements():
    req, dec = requirements(), declared()
    assert req == dec, f"requirements.txt {req} != pyproject.toml {dec}"
    assert all(v.startswith(">=") for v in dec.values()), dec


def test_version_is_the_newest_release():
    """The package's version, in pyproject.toml and in twomem_post.__version__, is the newest
    release of CHANGELOG.md, as `twomem --version` is (tests/regression/test_docs.py)."""
    changelog = (ROOT.parent / "CHANGELOG.md").read_text()
    newest = re.search(r"^## \[(\d+\.\d+\.\d+)\]", changelog, re.M)
    assert newest, "CHANGELOG.md has no release heading '## [X.Y.Z] - date'"
    project = re.search(r'^version\s*=\s*"([^"]+)"', (ROOT / "pyproject.toml").read_text(), re.M)
    package = re.search(r'^__version__\s*=\s*"([^"]+)"', (ROOT / "twomem_post" / "__init__.py").read_text(), re.M)
    assert project and project.group(1) == newest.group(1), "pyproject.toml's version is not CHANGELOG.md's newest"
    assert package and package.group(1) == newest.group(1), "twomem_post.__version__ is not CHANGELOG.md's newest"
