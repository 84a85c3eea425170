"""The layer rules of docs/architecture.md, checked on the code as it is."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DJANGO_CODE = [REPO / "core", REPO / "portal", REPO / "bookings"]


def _python_files(roots: list[Path]) -> list[Path]:
    return [p for root in roots for p in root.rglob("*.py") if "migrations" not in p.parts]


def test_the_import_contracts_hold():
    """web → runs → experiments → bookings → shared; the agent imports nothing of Django."""
    lint_imports = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    assert lint_imports, "import-linter is installed with the dev packages"
    result = subprocess.run(
        [lint_imports, "--no-cache"], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert "0 broken" in result.stdout


def test_no_import_inside_a_function_dodges_a_cycle():
    found = []
    for path in _python_files(DJANGO_CODE):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                for inner in ast.walk(node):
                    if isinstance(inner, ast.Import | ast.ImportFrom):
                        found.append(f"{path.relative_to(REPO)}:{inner.lineno}")
    assert not found, found


def test_nothing_below_the_portal_imports_from_it():
    """``core`` (the shared layer) and ``bookings`` sit below ``portal``: the tree is the
    layering, so neither imports anything of ``portal``."""
    found = []
    for path in _python_files([REPO / "core", REPO / "bookings"]):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            if any(name == "portal" or name.startswith("portal.") for name in names):
                found.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert not found, found


def test_bookings_never_names_a_web_page():
    found = []
    for path in _python_files([REPO / "bookings"]):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") in {
                "reverse",
                "reverse_lazy",
                "redirect",
            }:
                found.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert not found, found


# -- Overlap, spelled in one place per language ------------------------------------------------
#
# Every period is half-open, ``[start, end)``. The condition "these two overlap" is written
# once in Python (``bookings/periods.py``), once for the portal's queries
# (``PeriodQuerySet.overlapping``; ``core.sql.overlap`` for its hand-written SQL) and once in
# the agent's SQL (``overlap_condition``). The check below finds every ordering comparison
# between a period's start and a period's end (Python, Django lookups and SQL text), and
# every min/max of several starts or several ends (clipping), and accepts them only in those
# places or on the allowlist, where each entry says why it is not an overlap test.

INTERVAL_CODE = [REPO / "core", REPO / "portal", REPO / "bookings", REPO / "basestation"]
# The names this code gives the two ends of a period (start_at/end_at, valid_from/valid_until,
# started_at/ended_at, start_s/end_s, period_start/period_end, window_end, _busy_until …).
_START_NAME = re.compile(r"(^|_)(start|starts|started|from)(_|$)")
_END_NAME = re.compile(r"(^|_)(end|ends|ended|until)(_|$)")
_ORDERING = (ast.Lt, ast.LtE, ast.Gt, ast.GtE)
_LOOKUP = re.compile(r"^(?:\w+__)?(\w+?)__(lt|lte|gt|gte)$")
_SQL_COMPARISON = re.compile(r"\b([a-z_]+)\s*(<=|>=|<|>)\s*(\?|%s|[a-z_]+)")

OVERLAP_PLACES = {
    ("bookings/periods.py", ""),
    ("bookings/models.py", "PeriodQuerySet.overlapping"),
    ("core/sql.py", "overlap"),
    ("basestation/store.py", "overlap_condition"),
}
# Comparisons of a start with an end that are not "do these two periods overlap".
NOT_OVERLAP = {
    # "The end must be after the start": a period must not be empty.
    ("bookings/apis.py", "RangeQuery.validate", "attrs['end'] <= attrs['start']"),
    ("bookings/models.py", "Reservation.Meta", "end_at__gt=models.F('start_at')"),
    ("bookings/models.py", "ReservationItem.Meta", "end_at__gt=models.F('start_at')"),
    ("bookings/models.py", "Blackout.Meta", "end_at__gt=models.F('start_at')"),
    ("portal/runs/models.py", "Run.Meta", "end_at__gt=models.F('start_at')"),
    ("bookings/rules.py", "_window_problems", "end_at <= start_at"),
    ("bookings/rules.py", "booking_problems", "end_at <= start_at"),
    ("bookings/services/reservations.py", "_create_check_request", "start_at < end_at"),
    ("bookings/services/reservations.py", "reservation_check", "start_at < end_at"),
    ("bookings/services/reservations.py", "reservation_reschedule", "start_at < end_at"),
    ("bookings/services/blackouts.py", "blackout_create", "end_at <= start_at"),
    # "Still to come": a booking that ends after now (an instant, not a period's start).
    ("bookings/queries.py", "quota_upcoming", "end_at > %s"),
    ("bookings/scheduler/adapter.py", "covering_window", "valid_from >= valid_until"),
    ("bookings/scheduler/omf.py", "lease_from_resource", "valid_from >= valid_until"),
    (
        "bookings/scheduler/standin/broker.py",
        "Broker._check_window",
        "valid_from_s >= valid_until_s",
    ),
    ("basestation/program.py", "parse_run_body", "end_at <= start_at"),
    ("portal/web/calendars.py", "_range", "end <= start"),
    # The stand-in broker plays the testbed's omf_sfa broker and models that broker's own
    # rule (half-open too, docs/integration.md); borrowing ours would hide a disagreement.
    (
        "bookings/scheduler/standin/broker.py",
        "Broker._clashes",
        "other.valid_from_s < valid_until_s",
    ),
    (
        "bookings/scheduler/standin/broker.py",
        "Broker._clashes",
        "other.valid_until_s > valid_from_s",
    ),
    # The emulated radio: whether a packet arrives while the receiver is still busy, an
    # instant against airtime rather than a booked period (and the agent imports no bookings).
    ("basestation/sim/rfm69.py", "EmulatedRFM69._receive", "self._busy_until > reception.start_s"),
    ("basestation/sim/robot.py", "FrameRadio.receive_air", "reception.start_s < self._tx_until_s"),
    (
        "basestation/sim/robot.py",
        "FrameRadio.receive_air",
        "reception.start_s < self._busy_until_s",
    ),
    # Retention: what ended before a cutoff, an instant rather than a period.
    ("basestation/store.py", "RunStore.purge_ended_before", "ended_at < ?"),
}


def _period_end(node: ast.expr) -> str | None:
    """Whether the expression names a period's start ("start"), its end ("end"), or neither."""
    if isinstance(node, ast.Call) and node.args and getattr(node.func, "attr", "") == "F":
        node = node.args[0]  # models.F("start_at")
    if isinstance(node, ast.Name):
        name = node.id
    elif isinstance(node, ast.Attribute):
        name = node.attr
    elif isinstance(node, ast.Subscript | ast.Constant):
        key = node.slice if isinstance(node, ast.Subscript) else node
        if not (isinstance(key, ast.Constant) and isinstance(key.value, str)):
            return None
        name = key.value
    else:
        return None
    return _end_kind(name)


def _end_kind(name: str) -> str | None:
    if _START_NAME.search(name.lower()):
        return "start"
    if _END_NAME.search(name.lower()):
        return "end"
    return None


def interval_comparisons(source: str, path: str) -> list[tuple[str, str, str]]:
    """Every comparison of a period's start with a period's end: ``(path, scope, code)``.

    ``scope`` is the qualified name of the enclosing class or function ("" at module level).
    """
    found: list[tuple[str, str, str]] = []

    def visit(node: ast.AST, scope: str) -> None:
        if isinstance(node, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            scope = f"{scope}.{node.name}" if scope else node.name
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            for op, left, right in zip(node.ops, operands, operands[1:], strict=False):
                ends = {_period_end(left), _period_end(right)}
                if isinstance(op, _ORDERING) and ends == {"start", "end"}:
                    found.append((path, scope, ast.unparse(ast.Compare(left, [op], [right]))))
        elif isinstance(node, ast.Call) and getattr(node.func, "id", "") in {"min", "max"}:
            # The latest start or the earliest end of several periods: clipping one to another.
            kinds = {_period_end(arg) for arg in node.args}
            if len(node.args) > 1 and kinds in ({"start"}, {"end"}):
                found.append((path, scope, ast.unparse(node)))
        elif isinstance(node, ast.keyword) and node.arg and (lookup := _LOOKUP.match(node.arg)):
            if {_end_kind(lookup.group(1)), _period_end(node.value)} == {"start", "end"}:
                found.append((path, scope, ast.unparse(node)))
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            for match in _SQL_COMPARISON.finditer(node.value):
                column, _, other = match.groups()
                # A parameter hides what it holds: an end compared with one counts.
                parameter = other in ("?", "%s") and _end_kind(column) is not None
                if parameter or {_end_kind(column), _end_kind(other)} == {"start", "end"}:
                    found.append((path, scope, match.group(0)))
        for child in ast.iter_child_nodes(node):
            visit(child, scope)

    visit(ast.parse(source), "")
    return found


def allowed(finding: tuple[str, str, str]) -> bool:
    """In one of the overlap places (or a function inside one), or on the allowlist."""
    path, scope, _ = finding
    in_place = any(
        path == place and (not where or scope == where or scope.startswith(f"{where}."))
        for place, where in OVERLAP_PLACES
    )
    return in_place or finding in NOT_OVERLAP


def test_no_period_comparison_outside_the_overlap_places():
    found = []
    seen = set()
    for path in _python_files(INTERVAL_CODE):
        relative = path.relative_to(REPO).as_posix()
        for finding in interval_comparisons(path.read_text(), relative):
            seen.add(finding)
            if not allowed(finding):
                found.append(finding)
    assert not found, (
        "compare periods with bookings/periods.py (Python), PeriodQuerySet.overlapping "
        "(queries), core.sql.overlap (portal SQL) or "
        "basestation.store.overlap_condition (agent SQL); a comparison that is "
        f"no overlap test goes on NOT_OVERLAP with why: {found}"
    )
    assert not NOT_OVERLAP - seen, f"NOT_OVERLAP names what is gone: {NOT_OVERLAP - seen}"


def test_the_period_check_sees_a_new_comparison():
    source = """
class Calendar:
    def busy(self, lease, start_at, end_at, seq, last_seq):
        if seq < last_seq or lease.valid_from <= lease.valid_from:
            return False  # neither compares a start with an end
        return lease.valid_from < end_at and start_at < lease.valid_until

def used_s(a_start, a_end, b_start, b_end):
    return (min(a_end, b_end) - max(a_start, b_start, key=None)).total_seconds()

def listed(qs, query):
    return qs.filter(end_at__gt=query["start"], start_at__lte=now)

SQL = "SELECT id FROM runs WHERE started_at < ? AND seq > ?"
PORTAL_SQL = "SELECT id FROM items WHERE end_at > %s"
"""
    assert interval_comparisons(source, "x.py") == [
        ("x.py", "Calendar.busy", "lease.valid_from < end_at"),
        ("x.py", "Calendar.busy", "start_at < lease.valid_until"),
        ("x.py", "used_s", "min(a_end, b_end)"),
        ("x.py", "used_s", "max(a_start, b_start, key=None)"),
        ("x.py", "listed", "end_at__gt=query['start']"),
        ("x.py", "", "started_at < ?"),
        ("x.py", "", "end_at > %s"),
    ]
    assert allowed(("bookings/periods.py", "clip", "max(start, window_start)"))
    assert allowed(("bookings/models.py", "PeriodQuerySet.overlapping", "end_at__gt=start_at"))
    assert not allowed(("bookings/models.py", "Reservation.overlapping", "end_at__gt=start_at"))
    assert not allowed(("bookings/quotas.py", "period_usage", "start_at < period_end"))


# --- Rooms of a size a reader can hold ------------------------------------------------------

PRODUCT_CODE = [
    REPO / name for name in ("core", "portal", "bookings", "basestation", "amazing_cli", "cad")
]
MODULE_MAX_LINES = 600
FUNCTION_MAX_LINES = 60
# A long module says why it is one thing, in a paragraph of its docstring that starts so.
ONE_THING = "One thing:"
LONG_FUNCTIONS_DOC = REPO / "docs" / "architecture.md"
LONG_FUNCTIONS_HEADING = "### Functions over 60 lines"


def _long_functions() -> set[tuple[str, str]]:
    found = set()
    for path in _python_files(PRODUCT_CODE):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                assert node.end_lineno is not None
                if node.end_lineno - node.lineno + 1 > FUNCTION_MAX_LINES:
                    found.add((str(path.relative_to(REPO)), node.name))
    return found


def _listed_long_functions() -> set[tuple[str, str]]:
    """The table under the heading: ``| `path` | `name` | reason |`` rows, each with a reason."""
    text = LONG_FUNCTIONS_DOC.read_text()
    assert LONG_FUNCTIONS_HEADING in text, f"{LONG_FUNCTIONS_DOC.name} lost its list"
    section = text.split(LONG_FUNCTIONS_HEADING, 1)[1].split("\n#", 1)[0]
    listed = set()
    for path, name, reason in re.findall(
        r"^\| `([^`]+)` \| `([^`]+)` \| ([^|]*) \|$", section, re.M
    ):
        assert reason.strip(), f"{path} {name}: listed without its reason"
        listed.add((path, name))
    return listed


def test_every_module_over_600_lines_says_it_is_one_thing():
    long = []
    for path in _python_files(PRODUCT_CODE):
        text = path.read_text()
        if text.count("\n") > MODULE_MAX_LINES:
            docstring = ast.get_docstring(ast.parse(text)) or ""
            if ONE_THING not in docstring:
                long.append(f"{path.relative_to(REPO)}: {text.count(chr(10))} lines")
    assert not long, f"split these, or say in the docstring ({ONE_THING!r}) why not: {long}"


def test_every_function_over_60_lines_is_listed_with_its_reason():
    found, listed = _long_functions(), _listed_long_functions()
    assert found - listed == set(), "list these in docs/architecture.md, with why, or split them"
    assert listed - found == set(), "these are no longer long: take them off the list"
