"""The README's findings are the reproduction report's generated findings, verbatim (issue 10).

``reports/quick/README.md`` writes its "## Findings" section from the claim verdicts
(``benchmark.runner.claims.findings``); the top-level README quotes it between two markers. Prose
cannot drift from the numbers: after a rerun, a stale quote fails this test until it is copied
again.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BEGIN = "<!-- findings: generated in reports/quick/README.md, copied verbatim (tested) -->"
END = "<!-- end of generated findings -->"


def report_findings(text: str) -> str:
    """The body of the report's ``## Findings`` section (up to the next ``## `` heading)."""
    head = "\n## Findings\n"
    if head not in text:
        raise AssertionError("reports/quick/README.md has no '## Findings' section")
    body = text.split(head, 1)[1].split("\n## ", 1)[0].strip()
    # The report's own lead line points at "the claims table below"; the README says where from.
    if body.startswith("Generated from"):
        body = body.split("\n\n", 1)[1] if "\n\n" in body else ""
    return body.strip()


def readme_quote(text: str) -> str:
    if BEGIN not in text or END not in text:
        raise AssertionError(f"README.md lacks the markers {BEGIN!r} ... {END!r}")
    return text.split(BEGIN, 1)[1].split(END, 1)[0].strip()


class TestReadmeFindings:
    def test_readme_quotes_the_generated_findings_verbatim(self):
        report = (ROOT / "reports" / "quick" / "README.md").read_text()
        readme = (ROOT / "README.md").read_text()
        assert readme_quote(readme) == report_findings(report)

    def test_quote_is_not_empty_and_names_verdicts(self):
        quote = report_findings((ROOT / "reports" / "quick" / "README.md").read_text())
        assert len(quote) > 100
        assert any(w in quote for w in ("supported", "contradicted", "not resolved"))

    def test_hand_written_numbers_appear_in_the_reports(self):
        # The README's own sentences around the quote (leakage, towns) cite table numbers; each
        # must be printed in a committed report of that reproduction, so none can drift.
        readme = (ROOT / "README.md").read_text()
        section = readme.split("## Findings so far", 1)[1].split("\n## ", 1)[0]
        section = section.split("**Continuity", 1)[0]
        own = section.replace(readme_quote(readme), "")
        reports = "".join(p.read_text() for p in (ROOT / "reports" / "quick").glob("*.md"))
        cited = re.findall(r"\d+\.\d\d\b", own)
        assert cited, "expected numbers cited from the tables"
        assert [n for n in cited if n not in reports] == []

    def test_helpers_find_the_sections(self):
        report = "# r\n\n## Findings\n\nGenerated from x.\n\nA is supported.\n\n## Claims\n\nx\n"
        assert report_findings(report) == "A is supported."
        readme = f"intro\n{BEGIN}\nA is supported.\n{END}\nrest"
        assert readme_quote(readme) == "A is supported."
