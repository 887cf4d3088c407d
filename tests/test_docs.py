"""The README a newcomer reads in ten minutes, and documentation whose links all work (issue 41).

The README stays short (at most 250 lines) and shows both commands (reproduce; install and test)
on its first screen; everything longer lives in ``docs/``. Every relative link in the README,
DEVELOPERS.md, ``docs/*.md`` and ``reports/**/*.md`` must name a file that exists, and a link with
an anchor (``file.md#section``) a heading of that file, as GitHub spells anchors.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FIRST_SCREEN = 40  # lines a newcomer sees before scrolling
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"```.*?```", flags=re.DOTALL)


def documents() -> list[Path]:
    files = [ROOT / "README.md", ROOT / "DEVELOPERS.md", *sorted((ROOT / "docs").glob("*.md"))]
    return files + sorted((ROOT / "reports").rglob("*.md"))


def links(text: str) -> list[str]:
    """Targets of Markdown links and images outside code blocks."""
    return [a or b for a, b in LINK.findall(FENCE.sub("", text))]


def github_anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = FENCE.sub("", path.read_text(encoding="utf-8"))
    return {github_anchor(h) for h in re.findall(r"^#{1,6} (.+)$", text, flags=re.MULTILINE)}


class TestReadme:
    def test_at_most_250_lines(self):
        lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
        assert len(lines) <= 250, f"README.md has {len(lines)} lines: move detail to docs/"

    def test_both_commands_on_the_first_screen(self):
        first = "\n".join((ROOT / "README.md").read_text().splitlines()[:FIRST_SCREEN])
        assert "uavbench reproduce" in first
        ci = (ROOT / ".ci" / "run").read_text()
        assert "python -m pytest" in first and "python -m pytest" in ci
        assert "pip install torch==2.13.0" in first

    def test_every_doc_is_linked_from_the_readme(self):
        readme = (ROOT / "README.md").read_text()
        docs = [p.name for p in (ROOT / "docs").glob("*.md")]
        assert [name for name in docs if f"](docs/{name})" not in readme] == []

    def test_glossary_defines_the_concepts(self):
        readme = (ROOT / "README.md").read_text()
        concepts = readme.split("## Concepts", 1)[1].split("\n## ", 1)[0]
        terms = ["Profile", "Spec", "Unit", "Shared encoder", "Protocol", "Claim", "Split"]
        terms += ["Non-learned reference", "Constant predictor", "swap probe"]
        for term in terms:
            assert f"**{term}**" in concepts, term


@pytest.mark.parametrize("path", documents(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path: Path):
    broken = []
    for target in links(path.read_text(encoding="utf-8")):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        resolved = (path.parent / file).resolve() if file else path
        if not resolved.exists():
            broken.append(f"{target} (no file {resolved})")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
            broken.append(f"{target} (no heading with anchor #{anchor})")
    assert broken == [], f"{path.relative_to(ROOT)}: broken links {broken}"


class TestHelpers:
    def test_github_anchor(self):
        assert github_anchor("Model contract (`benchmark/models`, `baselines/`)") == (
            "model-contract-benchmarkmodels-baselines"
        )
        assert github_anchor("Browsing results in MLflow") == "browsing-results-in-mlflow"

    def test_links_skip_code_blocks(self):
        text = "[a](x.md) ![i](y.png)\n```\n[b](z.md)\n```\n"
        assert links(text) == ["x.md", "y.png"]
