"""``make audit``: known vulnerabilities in the Python and npm packages the project installs.

pip-audit checks the virtualenv's packages against PyPI's advisory data (its ``pypi``
service: the JSON API of each package's release), ``npm audit`` the npm packages of
``package-lock.json`` against the npm registry's advisories. An advisory found is a failure
unless ``deploy/audit-allowlist.toml`` accepts it, with a reason and a date to look at it
again (past that date the entry no longer counts).

A package the advisory service could not look up is not a pass: pip-audit reports it as
"skipped" and still exits 0, and ``npm audit`` answers an error instead of a report when its
endpoint is out of reach. Either makes the audit *incomplete*, which fails too, unless
``--incomplete=warn`` (where the advisory services cannot be reached, e.g. a network that
lets only package downloads through): then it says, loudly, what was not audited.

Exit codes: 0 clean (or incomplete with ``warn``), 1 an advisory not accepted, 2 incomplete.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import re
import subprocess
import sys
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
ALLOWLIST = REPO / "deploy" / "audit-allowlist.toml"
GHSA = re.compile(r"GHSA(-[0-9a-z]{4}){3}")


@dataclass(frozen=True)
class Finding:
    ecosystem: str  # "python" | "npm"
    package: str
    version: str
    ids: frozenset[str]  # the advisory's id and its aliases (PYSEC-…, GHSA-…, CVE-…)
    summary: str

    def describe(self) -> str:
        ids = ", ".join(sorted(self.ids))
        return f"{self.ecosystem} {self.package} {self.version}: {ids} {self.summary}"


@dataclass
class Report:
    findings: list[Finding] = field(default_factory=list)
    # What could not be audited, and why (one line each).
    unaudited: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Accepted:
    id: str
    package: str
    reason: str
    review_by: dt.date

    def covers(self, finding: Finding) -> bool:
        return self.package.lower() == finding.package.lower() and self.id in finding.ids


def load_allowlist(text: str, *, today: dt.date) -> tuple[list[Accepted], list[str]]:
    """The entries in force, and the problems of the file (each a failure)."""
    data = tomllib.loads(text)
    accepted, problems = [], []
    for number, entry in enumerate(data.get("advisory", []), start=1):
        missing = [key for key in ("id", "package", "reason", "review_by") if not entry.get(key)]
        if missing:
            problems.append(f"allowlist entry {number}: missing {', '.join(missing)}")
            continue
        review_by = entry["review_by"]
        if not isinstance(review_by, dt.date):
            problems.append(f"allowlist entry {number}: review_by is a date (2027-01-31)")
            continue
        if review_by < today:
            problems.append(
                f"allowlist entry {number} ({entry['id']} in {entry['package']}) was to be "
                f"reviewed by {review_by}: look at it again and set a new date, or remove it"
            )
            continue
        accepted.append(
            Accepted(
                id=str(entry["id"]),
                package=str(entry["package"]),
                reason=str(entry["reason"]),
                review_by=review_by,
            )
        )
    return accepted, problems


def parse_pip_audit(output: Mapping[str, Any]) -> Report:
    """pip-audit's ``--format json``: each dependency's advisories, or why it was skipped."""
    report = Report()
    for dependency in output.get("dependencies", []):
        name = str(dependency.get("name", "?"))
        reason = dependency.get("skip_reason")
        if reason:
            if "editable" not in reason:  # the project itself, installed from this tree
                report.unaudited.append(f"python {name}: {reason}")
            continue
        for vuln in dependency.get("vulns", []):
            report.findings.append(
                Finding(
                    ecosystem="python",
                    package=name,
                    version=str(dependency.get("version", "?")),
                    ids=frozenset([str(vuln["id"]), *map(str, vuln.get("aliases", []))]),
                    summary=_fixed_in(vuln.get("fix_versions", [])),
                )
            )
    return report


def parse_npm_audit(output: Mapping[str, Any]) -> Report:
    """``npm audit --json`` (report version 2), or the error it answers instead."""
    report = Report()
    if "vulnerabilities" not in output:
        message = output.get("message") or output.get("error") or "no report"
        report.unaudited.append(f"npm: the registry's audit endpoint answered: {message}")
        return report
    for name, vulnerability in output["vulnerabilities"].items():
        for via in vulnerability.get("via", []):
            if not isinstance(via, dict):
                continue  # vulnerable through another package, which is listed itself
            ids = {str(via.get("source", "")), _ghsa(str(via.get("url", "")))}
            report.findings.append(
                Finding(
                    ecosystem="npm",
                    package=str(name),
                    version=str(via.get("range", "?")),
                    ids=frozenset(i for i in ids if i),
                    summary=f"({via.get('severity', '?')}) {via.get('title', '')}",
                )
            )
    return report


def _ghsa(url: str) -> str:
    found = GHSA.search(url)
    return found.group(0) if found else ""


def _fixed_in(versions: Iterable[str]) -> str:
    versions = list(versions)
    return f"(fixed in {', '.join(versions)})" if versions else "(no fixed version yet)"


def judge(report: Report, accepted: list[Accepted]) -> tuple[list[Finding], list[Finding]]:
    """The findings not accepted, and the accepted ones."""
    refused = [f for f in report.findings if not any(a.covers(f) for a in accepted)]
    allowed = [f for f in report.findings if f not in refused]
    return refused, allowed


def _run_json(argv: list[str]) -> dict[str, Any]:
    # The tools of this virtualenv and npm, with fixed arguments.
    done = subprocess.run(  # noqa: S603
        argv, cwd=REPO, capture_output=True, text=True, timeout=900
    )
    try:
        parsed = json.loads(done.stdout)
    except ValueError:
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        return {"message": f"{argv[0]} exited {done.returncode}: {' | '.join(tail)}"}
    return parsed if isinstance(parsed, dict) else {"message": "not a JSON object"}


def audit() -> Report:
    pip_audit = Path(sys.executable).with_name("pip-audit")
    python = _run_json(
        [str(pip_audit), "--format", "json", "--progress-spinner", "off", "--skip-editable"]
    )
    report = parse_pip_audit(python)
    if "dependencies" not in python:
        report.unaudited.append(f"python: pip-audit gave no report: {python.get('message')}")
    npm = parse_npm_audit(_run_json(["npm", "audit", "--json"]))
    report.findings += npm.findings
    report.unaudited += npm.unaudited
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--incomplete",
        choices=["fail", "warn"],
        default="fail",
        help="what an audit that could not reach its advisory data does (default: fail)",
    )
    args = parser.parse_args(argv)
    accepted, problems = load_allowlist(ALLOWLIST.read_text(), today=dt.date.today())
    report = audit()
    refused, allowed = judge(report, accepted)
    for finding in allowed:
        print(f"accepted (deploy/audit-allowlist.toml): {finding.describe()}")
    for finding in refused:
        print(f"VULNERABLE: {finding.describe()}")
    for problem in problems:
        print(f"ALLOWLIST: {problem}")
    for ecosystem in ("python", "npm"):
        lines = [line for line in report.unaudited if line.startswith(ecosystem)]
        if lines:
            print(f"NOT AUDITED ({ecosystem}): {len(lines)}, e.g. {lines[0]}")
    if refused or problems:
        return 1
    if report.unaudited:
        if args.incomplete == "warn":
            print("the audit is INCOMPLETE (--incomplete=warn): run `make audit` where the "
                  "advisory services are reachable")  # fmt: skip
            return 0
        return 2
    print(f"no known vulnerabilities ({len(allowed)} accepted in deploy/audit-allowlist.toml)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
