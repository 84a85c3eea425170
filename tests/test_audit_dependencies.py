"""``make audit`` (deploy/audit_dependencies.py): advisories fail unless accepted with a
reason and a review date, and an audit that could not look packages up is no pass."""

from __future__ import annotations

import datetime as dt
import importlib.util
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location(
    "audit_dependencies", REPO / "deploy" / "audit_dependencies.py"
)
assert _spec is not None
assert _spec.loader is not None
audit = importlib.util.module_from_spec(_spec)
sys.modules["audit_dependencies"] = audit
_spec.loader.exec_module(audit)

TODAY = dt.date(2026, 11, 25)
PIP_AUDIT = {
    "dependencies": [
        {
            "name": "django",
            "version": "5.2.19",
            "vulns": [
                {
                    "id": "PYSEC-2026-1",
                    "fix_versions": ["5.2.20"],
                    "aliases": ["GHSA-aaaa-bbbb-cccc", "CVE-2026-0001"],
                }
            ],
        },
        {"name": "requests", "version": "2.34.2", "vulns": []},
        {"name": "amazing-mobile-node", "skip_reason": "distribution marked as editable"},
    ],
    "fixes": [],
}
NPM_AUDIT = {
    "auditReportVersion": 2,
    "vulnerabilities": {
        "chart.js": {
            "name": "chart.js",
            "severity": "high",
            "via": [
                {
                    "source": 1096000,
                    "name": "chart.js",
                    "title": "Prototype pollution",
                    "url": "https://github.com/advisories/GHSA-dddd-eeee-ffff",
                    "severity": "high",
                    "range": "<4.5.0",
                }
            ],
        },
        "luxon3-wrapper": {"name": "luxon3-wrapper", "via": ["chart.js"]},
    },
}


def _allow(entries: str) -> list:
    accepted, problems = audit.load_allowlist(entries, today=TODAY)
    assert not problems, problems
    return accepted


def test_an_advisory_fails_the_audit_until_accepted_by_any_of_its_ids():
    report = audit.parse_pip_audit(PIP_AUDIT)
    report.findings += audit.parse_npm_audit(NPM_AUDIT).findings
    assert not report.unaudited  # the project itself (editable) is not a gap
    refused, allowed = audit.judge(report, [])
    assert [(f.ecosystem, f.package) for f in refused] == [
        ("python", "django"),
        ("npm", "chart.js"),
    ]
    assert "fixed in 5.2.20" in refused[0].describe()
    assert "GHSA-dddd-eeee-ffff" in refused[1].ids

    accepted = _allow(
        '[[advisory]]\nid = "CVE-2026-0001"\npackage = "Django"\n'
        'reason = "only the admin\'s password reset, which is off"\nreview_by = 2027-01-31\n'
        '[[advisory]]\nid = "GHSA-dddd-eeee-ffff"\npackage = "chart.js"\n'
        'reason = "no user data reaches the chart options"\nreview_by = 2027-01-31\n'
    )
    refused, allowed = audit.judge(report, accepted)
    assert refused == []
    assert len(allowed) == 2
    # An entry names one package: the same id elsewhere is still refused.
    other = _allow(
        '[[advisory]]\nid = "CVE-2026-0001"\npackage = "flask"\nreason = "x"\n'
        "review_by = 2027-01-31\n"
    )
    assert [f.package for f in audit.judge(report, other)[0]] == ["django", "chart.js"]


@pytest.mark.parametrize(
    ("entry", "problem"),
    [
        ('id = "X-1"\npackage = "django"\nreason = "r"\nreview_by = 2026-11-24', "reviewed by"),
        ('id = "X-1"\npackage = "django"\nreview_by = 2027-01-01', "missing reason"),
        ('id = "X-1"\npackage = "django"\nreason = "r"\nreview_by = "soon"', "is a date"),
    ],
    ids=["past its review date", "no reason", "no date"],
)
def test_an_allowlist_entry_without_a_reason_or_past_its_review_date_counts_for_nothing(
    entry: str, problem: str
):
    accepted, problems = audit.load_allowlist(f"[[advisory]]\n{entry}\n", today=TODAY)
    assert accepted == []
    assert problem in problems[0]


def test_packages_the_service_could_not_look_up_make_the_audit_incomplete():
    # What pip-audit answers (exit 0, "No known vulnerabilities found") when the advisory
    # service does not know the releases, and what npm audit answers when its endpoint fails.
    skipped = {
        "dependencies": [
            {
                "name": "django",
                "skip_reason": "Dependency not found on PyPI and could not be "
                "audited: django (5.2.19)",
            },
        ]
    }
    refused_npm = {"message": "405 Method Not Allowed - POST …/advisories/bulk", "statusCode": 405}
    python, npm = audit.parse_pip_audit(skipped), audit.parse_npm_audit(refused_npm)
    assert python.findings == npm.findings == []
    assert python.unaudited == [f"python django: {skipped['dependencies'][0]['skip_reason']}"]
    assert "405 Method Not Allowed" in npm.unaudited[0]


def test_the_allowlist_in_the_repository_is_valid():
    accepted, problems = audit.load_allowlist(audit.ALLOWLIST.read_text(), today=dt.date.today())
    assert not problems, problems
    assert all(entry.reason.strip() for entry in accepted)
