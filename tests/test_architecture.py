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
    ("portal/queue/slots.py", "allowed_periods", "start >= end"),
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


# --- Hand-written SQL, in its homes only ------------------------------------------------------
#
# The portal asks the database through the ORM. SQL written by hand lives in each app's
# ``queries.py`` and in ``core/sql.py`` (the helpers and core's own statements); the agent's
# in its store (plain sqlite3), the stand-in broker's in its own. Outside these homes no
# string holds SQL, and only ``core/sql.py`` asks which database answers. Inside them nothing
# is formatted into an f-string but what can only make safe text: a call on SAFE_CALLS, a
# number (a numeric format spec), an UPPER_CASE constant, a helper of the home that returns
# only such text, or a local (or loop variable) made only of those; ``.format`` and ``%`` do
# not build SQL there at all. That is why pyproject.toml turns ruff's S608 (SQL built from
# strings, a guess) off in these homes alone. An exception's message is no SQL.

SQL_CODE = [REPO / name for name in ("core", "portal", "bookings", "basestation", "amazing_cli")]
SQL_HOMES = {
    "core/sql.py",
    "basestation/store.py",
    # The stand-in broker plays the testbed's scheduler in a process of its own, without
    # Django (import-linter): its file's few constant statements stay beside it.
    "bookings/scheduler/standin/store.py",
}
# Upper-case keywords in the shape of a statement: prose and names do not match. A PRAGMA is
# a connection's setting (the settings give SQLite's one), not a query.
SQL_TEXT = re.compile(
    r"\bSELECT\b.*\bFROM\b|\bSELECT\s+(?:\d|\w+\()|\bINSERT\s+(?:OR\s+\w+\s+)?INTO\b"
    r"|\bDELETE\s+FROM\b|\bUPDATE\s+\S+\s+SET\b|\bWITH\s+\w+\s+AS\b|\bCOPY\s*\("
    r"|\bCOPY\s+\S+.*\b(?:FROM\s+STDIN|TO\s+STDOUT)\b"
    r"|\b(?:CREATE|ALTER|DROP)\s+(?:TEMPORARY\s+|TEMP\s+)?(?:TABLE|INDEX|VIEW|TRIGGER)\b",
    re.S,
)
# What may be formatted into SQL, and why it is safe text whatever its arguments.
SAFE_CALLS = {
    "sql.table": "a model's table name, quoted by the database's own rule",
    "sql.column_type": "a model field's column type, as its migration made it",
    "sql.placeholders": "parameter marks, nothing else",
    "sql.instant": "a fixed expression around a name sql.identifier checked",
    "sql.overlap": "the fixed condition around an alias sql.identifier checked",
    "sql.identifier": "the name itself, refused unless a plain lower-case name",
    "int": "a number",
}
# The same helpers inside their own module, and the agent's (its store imports nothing of
# core): its overlap condition and its check of a column name.
SAFE_CALLS_IN = {
    "core/sql.py": {name.removeprefix("sql.") for name in SAFE_CALLS if name.startswith("sql.")},
    "basestation/store.py": {"overlap_condition", "_column_name"},
}
_CONSTANT_NAME = re.compile(r"_?[A-Z][A-Z0-9_]*")
_NUMBER_SPEC = re.compile(r"[^{}]*[bcdeEfFgGnoxX%]")
_SCOPES = (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)
_COMPREHENSIONS = (ast.ListComp, ast.SetComp, ast.GeneratorExp, ast.DictComp)


def is_sql_home(path: str) -> bool:
    return path in SQL_HOMES or path.endswith("/queries.py")


def _text(node: ast.AST) -> str | None:
    """A string literal's text, an f-string's with ``{}`` for each value; else None."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(str(v.value) if isinstance(v, ast.Constant) else "{}" for v in node.values)
    return None


def _docstrings(tree: ast.Module) -> set[ast.AST]:
    found: set[ast.AST] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            first = node.body[0] if node.body else None
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                found.add(first.value)
    return found


def sql_outside_homes(source: str, path: str) -> list[tuple[str, int]]:
    """Every string literal or f-string holding SQL outside the homes: ``(path, line)``."""
    if is_sql_home(path):
        return []
    tree = ast.parse(source)
    docstrings = _docstrings(tree)
    inner = {v for n in ast.walk(tree) if isinstance(n, ast.JoinedStr) for v in n.values}
    return sorted(
        (path, node.lineno)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant | ast.JoinedStr)
        and node not in docstrings
        and node not in inner
        and SQL_TEXT.search(_text(node) or "")
    )


class _Element(ast.expr):
    """The ``index``-th of what ``call`` returns, as ``a, b = call()`` binds it."""

    def __init__(self, call: ast.Call, index: int) -> None:
        super().__init__()
        self.call, self.index = call, index


class _SqlParts:
    """Which expressions of one module can only make safe text (see the comment above)."""

    def __init__(self, tree: ast.Module, path: str) -> None:
        self.path = path
        self.tree = tree
        self.parent = {c: p for p in ast.walk(tree) for c in ast.iter_child_nodes(p)}
        self.functions = {
            n.name: n for n in tree.body if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)
        }
        self.visiting: set[tuple[int, str]] = set()

    def safe(self, node: ast.AST | None) -> bool:
        if isinstance(node, ast.Constant):
            return True
        if isinstance(node, ast.JoinedStr):
            return all(self.value_safe(v) for v in node.values if isinstance(v, ast.FormattedValue))
        if isinstance(node, ast.Name):
            return bool(_CONSTANT_NAME.fullmatch(node.id)) or self.name_safe(node, node.id)
        if isinstance(node, ast.Attribute | ast.Subscript):
            return self.safe(node.value)  # a field or an element of what is safe
        if isinstance(node, ast.Call):
            return self.call_safe(node)
        if isinstance(node, _Element):
            return self.call_safe(node.call, node.index)
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
            return self.safe(node.left) and self.safe(node.right)
        if isinstance(node, ast.IfExp):
            return self.safe(node.body) and self.safe(node.orelse)
        if isinstance(node, ast.Tuple | ast.List):
            return all(self.safe(e) for e in node.elts)
        if isinstance(node, ast.ListComp | ast.GeneratorExp):
            return self.safe(node.elt)
        return False

    def value_safe(self, value: ast.FormattedValue) -> bool:
        spec = _text(value.format_spec) if value.format_spec else None
        return bool(spec and _NUMBER_SPEC.fullmatch(spec)) or self.safe(value.value)

    def call_safe(self, node: ast.Call, index: int | None = None) -> bool:
        """Whether the call returns safe text (its ``index``-th part, for a tuple)."""
        callee = ast.unparse(node.func)
        if callee in SAFE_CALLS or callee in SAFE_CALLS_IN.get(self.path, set()):
            return True
        func = node.func
        if isinstance(func, ast.Attribute) and func.attr == "join" and len(node.args) == 1:
            return isinstance(func.value, ast.Constant) and self.safe(node.args[0])
        if isinstance(func, ast.Attribute) and func.attr in ("items", "keys", "values"):
            return self.safe(func.value)  # iterating over what is safe
        if isinstance(func, ast.Name) and func.id in self.functions:
            return self.returns_safe(self.functions[func.id], index)
        return False

    def returns_safe(
        self, function: ast.FunctionDef | ast.AsyncFunctionDef, index: int | None
    ) -> bool:
        """Whether every ``return`` of a function of this module is safe text (with its
        parameters taken as unsafe); its ``index``-th part when it returns a tuple."""
        key = (id(function), f"return {index}")
        if key in self.visiting:
            return True  # recursion: as for a name bound from itself
        self.visiting.add(key)
        returns = [n.value for n in self._own_nodes(function) if isinstance(n, ast.Return)]
        if index is not None:
            returns = [v.elts[index] if isinstance(v, ast.Tuple) else None for v in returns]
        safe = bool(returns) and all(self.safe(value) for value in returns)
        self.visiting.discard(key)
        return safe

    def _own_nodes(self, scope: ast.AST) -> list[ast.AST]:
        """The nodes of ``scope`` outside any scope or comprehension nested in it."""
        found, todo = [], list(ast.iter_child_nodes(scope))
        while todo:
            node = todo.pop()
            found.append(node)
            if not isinstance(node, (*_SCOPES, *_COMPREHENSIONS)):
                todo.extend(ast.iter_child_nodes(node))
        return found

    def name_safe(self, at: ast.AST, name: str) -> bool:
        """Whether every binding of ``name`` seen from ``at`` is safe: a comprehension's
        target first, then its scope's assignments, then the module's."""
        node: ast.AST | None = at
        while node is not None:
            bound: list[ast.AST | None] | None = None
            if isinstance(node, _COMPREHENSIONS):
                bound = [g.iter for g in node.generators if _binds(g.target, name)] or None
            elif isinstance(node, _SCOPES):
                bound = self._bindings(node, name)
            if bound is not None:
                key = (id(node), name)
                if key in self.visiting:
                    # Bound from itself (``x = f"({x})"``): safe if every binding is, given
                    # that; the first binding cannot name it, so that one decides.
                    return True
                self.visiting.add(key)
                safe = all(self.safe(value) for value in bound)
                self.visiting.discard(key)
                return safe
            node = self.parent.get(node)
        return False

    def _bindings(self, scope: ast.AST, name: str) -> list[ast.AST | None] | None:
        """What ``name`` is bound to in ``scope`` (None for what no expression says, such as
        a parameter); None when the scope does not bind it."""
        values: list[ast.AST | None] = []
        if isinstance(scope, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
            arguments = scope.args
            every = [*arguments.posonlyargs, *arguments.args, *arguments.kwonlyargs]
            every += [a for a in (arguments.vararg, arguments.kwarg) if a is not None]
            values += [None for a in every if a.arg == name]
        for node in self._own_nodes(scope):
            if isinstance(node, ast.Assign | ast.AugAssign | ast.AnnAssign | ast.NamedExpr):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                values += [self._bound(t, node.value, name) for t in targets if _binds(t, name)]
            elif isinstance(node, ast.For | ast.AsyncFor) and _binds(node.target, name):
                values.append(node.iter)  # an element of what is iterated
            elif (
                (isinstance(node, ast.withitem) and _binds(node.optional_vars, name))
                or (isinstance(node, ast.ExceptHandler) and node.name == name)
                or (isinstance(node, ast.alias) and (node.asname or node.name) == name)
            ):
                values.append(None)  # a context, an exception, an import: nothing known
            elif (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr in ("append", "extend", "insert")
                and _binds(node.func.value, name)
            ):
                values.append(node.args[-1] if node.args else None)  # what the list gains
        return values or None

    @staticmethod
    def _bound(target: ast.AST, value: ast.AST | None, name: str) -> ast.AST | None:
        """What ``target = value`` binds ``name`` to: the matching part when both sides are
        tuples, the matching part of what a call returns when only the target is one."""
        if isinstance(target, ast.Tuple | ast.List):
            for index, element in enumerate(target.elts):
                if not _binds(element, name):
                    continue
                if isinstance(value, ast.Tuple | ast.List) and len(value.elts) == len(target.elts):
                    return _SqlParts._bound(element, value.elts[index], name)
                if isinstance(value, ast.Call) and isinstance(element, ast.Name):
                    return _Element(value, index)
        return value


def _binds(target: ast.AST | None, name: str) -> bool:
    return target is not None and any(
        isinstance(n, ast.Name) and n.id == name for n in ast.walk(target)
    )


def sql_formatted_unsafely(source: str, path: str) -> list[tuple[str, int, str]]:
    """In a home: every f-string value that is not safe text, every ``.format`` and every
    ``%`` on a string: ``(path, line, code)``."""
    if not is_sql_home(path):
        return []
    tree = ast.parse(source)
    parts = _SqlParts(tree, path)
    messages = {
        n for r in ast.walk(tree) if isinstance(r, ast.Raise) for n in ast.walk(r)
    }  # an exception's message is no SQL
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr) and node not in messages:
            for value in node.values:
                if isinstance(value, ast.FormattedValue) and not parts.value_safe(value):
                    found.append((path, node.lineno, ast.unparse(value.value)))
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "format":
            found.append((path, node.lineno, ast.unparse(node.func)))
        elif (
            isinstance(node, ast.BinOp)
            and isinstance(node.op, ast.Mod)
            and _text(node.left) is not None
        ):
            found.append((path, node.lineno, ast.unparse(node)))
    return sorted(found)


def vendor_asked(source: str, path: str) -> list[tuple[str, int]]:
    """Every ``….connection.vendor`` outside ``core/sql.py``: ``(path, line)``."""
    if path == "core/sql.py":
        return []
    return [
        (path, node.lineno)
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Attribute)
        and node.attr == "vendor"
        and ast.unparse(node.value).split(".")[-1] == "connection"
    ]


def _sql_code() -> list[tuple[str, str]]:
    return [(p.relative_to(REPO).as_posix(), p.read_text()) for p in _python_files(SQL_CODE)]


def test_sql_is_written_only_in_its_homes():
    found = [f for path, source in _sql_code() for f in sql_outside_homes(source, path)]
    assert not found, f"move this SQL into the app's queries.py (or core/sql.py): {found}"


def test_sql_is_built_only_from_safe_parts():
    found = [f for path, source in _sql_code() for f in sql_formatted_unsafely(source, path)]
    assert not found, (
        "format into SQL only a helper on SAFE_CALLS, int(...), an UPPER_CASE constant or a "
        f"local made of them; every value else is a bound parameter: {found}"
    )


def test_only_core_sql_asks_which_database():
    found = [f for path, source in _sql_code() for f in vendor_asked(source, path)]
    assert not found, f"ask core.sql.is_postgresql() (or its neighbours) instead: {found}"


def test_the_sql_checks_see_what_they_refuse():
    source = '''
from core import sql

TABLE = "runs"
ANSWER = "SELECT 1"

def read(run_id, order, names):
    """SELECT id FROM runs: a docstring is no SQL."""
    ids = sql.placeholders(len(names))
    where = f"id IN ({ids})"
    where += f" AND {order}"
    columns = ", ".join(f"{n}" for n in names)
    fixed = ", ".join(f"x.{n}" for n in ("a", "b"))
    fixed = f"({fixed})"
    if connection.vendor == "sqlite":
        raise ValueError(f"no {order}")
    return (
        f"SELECT {columns}, {fixed} FROM {TABLE} WHERE {where} AND n > {run_id:d}",
        "DELETE FROM {} WHERE id = {}".format(TABLE, run_id),
        "UPDATE runs SET x = %s" % run_id,
        f"SELECT * FROM {sql.table(Run)} WHERE id = {int(run_id)}",
    )
'''
    assert sql_outside_homes(source, "portal/x.py") == [
        ("portal/x.py", 5),
        ("portal/x.py", 18),
        ("portal/x.py", 19),
        ("portal/x.py", 20),
        ("portal/x.py", 21),
    ]
    assert sql_outside_homes(source, "portal/runs/queries.py") == []
    assert sql_formatted_unsafely(source, "portal/x.py") == []
    # The local ``where`` gains the parameter ``order``; ``columns`` is made of ``names``.
    assert sql_formatted_unsafely(source, "portal/runs/queries.py") == [
        ("portal/runs/queries.py", 11, "order"),
        ("portal/runs/queries.py", 12, "n"),
        ("portal/runs/queries.py", 18, "columns"),
        ("portal/runs/queries.py", 18, "where"),
        ("portal/runs/queries.py", 19, "'DELETE FROM {} WHERE id = {}'.format"),
        ("portal/runs/queries.py", 20, "'UPDATE runs SET x = %s' % run_id"),
    ]
    assert vendor_asked(source, "bookings/x.py") == [("bookings/x.py", 15)]
    assert vendor_asked(source, "core/sql.py") == []


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
