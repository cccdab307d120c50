"""The README and docs/ hold together: every relative link points to a file that exists,
and every link to a heading (``file.md#anchor``) names a heading of that file."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _without_code(text: str) -> str:
    """The text outside fenced code blocks and inline code spans."""
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    return re.sub(r"`[^`\n]*`", "", text)


def _anchors(path: Path) -> set[str]:
    """GitHub's anchors of a Markdown file's headings."""
    out = set()
    for line in re.sub(r"```.*?```", "", path.read_text(), flags=re.S).splitlines():
        m = re.match(r"#{1,6}\s+(.*)", line)
        if m:
            title = m.group(1).strip().lower()
            title = re.sub(r"[^\w\- ]", "", title)
            out.add(title.replace(" ", "-"))
    return out


def _links(page: Path):
    for m in LINK.finditer(_without_code(page.read_text())):
        target = m.group(1)
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        yield target


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    broken = []
    for target in _links(page):
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            broken.append(f"{target}: no heading with that anchor")
    assert not broken, f"{page.relative_to(ROOT)}: " + "; ".join(broken)


def test_the_readme_is_a_front_door():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 300
    assert sum(line.endswith("# install, run the tests") for line in text.splitlines()) == 1
    assert sum(line.endswith("# install, run the main job") for line in text.splitlines()) == 1


def test_config_files_point_at_schemas_that_exist():
    """Each ``# Schema (types, meaning): FILE:CLASS`` comment in conf/ names a class that
    the file defines."""
    import re

    pointers = [(path, m.group(1), m.group(2)) for path in sorted((ROOT / "conf").rglob("*.yaml"))
                for m in re.finditer(r"Schema \(types, meaning\): (\S+):(\w+)", path.read_text())]
    assert pointers
    for path, source, cls in pointers:
        assert f"class {cls}" in (ROOT / source).read_text(), f"{path}: {source}:{cls}"


def test_domain_config_files_point_at_their_registered_schema():
    """conf/domain/<name>.yaml names the schema the registry has for <name>."""
    import re

    from pipeline.domains import DOMAINS, domain_schema, has_yaml

    for name in filter(has_yaml, DOMAINS):
        text = (ROOT / "conf" / "domain" / f"{name}.yaml").read_text()
        source, cls = re.search(r"Schema \(types, meaning\): (\S+):(\w+)", text).groups()
        schema = domain_schema(name)
        assert (source, cls) == (schema.__module__.replace(".", "/") + ".py", schema.__name__)
