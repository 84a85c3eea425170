"""The booking dialogs' reading of typed times (``wall_clock.js``, in Node with the luxon the
pages load) gives the same answers as the portal's rule (``core/wall_clock.py``, which the
Book page's form and every service use): the same instant for every minute of both 2027
transition days in Lisbon and of random days in several zones, the same refusal, word for
word, for a time the clocks skip."""

from __future__ import annotations

import json
import shutil
import subprocess
from datetime import UTC, datetime, timedelta
from zoneinfo import ZoneInfo

from hypothesis import given, settings
from hypothesis import strategies as st

from bench.stack import REPO
from core.wall_clock import NonexistentLocalTime, local_instant

SCRIPT = REPO / "portal" / "web" / "static" / "web" / "wall_clock.js"
LUXON = REPO / "node_modules" / "luxon"
ZONES = ("Europe/Lisbon", "Europe/Berlin", "America/New_York", "Australia/Sydney", "UTC")

RUNNER = """
const fs = require("fs");
global.window = {};
global.luxon = require(process.argv[1]);
eval(fs.readFileSync(process.argv[2], "utf8"));
const asked = JSON.parse(fs.readFileSync(0, "utf8"));
const answers = asked.map(([value, zone]) => window.AmazingWallClock.localInstant(value, zone));
process.stdout.write(JSON.stringify(answers));
"""


def _in_javascript(asked: list[tuple[str, str]]) -> list[dict]:
    node = shutil.which("node")
    assert node, "Node.js is missing (the Makefile's npm needs it too)"
    done = subprocess.run(
        [node, "-e", RUNNER, str(LUXON), str(SCRIPT)],
        input=json.dumps(asked),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    answers = json.loads(done.stdout)
    assert isinstance(answers, list)
    return answers


def _in_python(value: str, zone: str) -> dict:
    wall = datetime.fromisoformat(value)
    try:
        instant = local_instant(wall, ZoneInfo(zone))
    except NonexistentLocalTime as exc:
        return {"error": str(exc)}
    return {"iso": instant.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")}


def _agree(asked: list[tuple[str, str]]) -> dict[str, dict]:
    """JavaScript's answers by typed value, each checked against Python's."""
    answers = _in_javascript(asked)
    for (value, zone), js in zip(asked, answers, strict=True):
        python = _in_python(value, zone)
        assert {k: js.get(k) for k in python} == python, (value, zone, js)
    return {value: js for (value, _), js in zip(asked, answers, strict=True)}


def _every_minute_of(day: str) -> list[str]:
    start = datetime.fromisoformat(day)
    return [(start + timedelta(minutes=m)).strftime("%Y-%m-%dT%H:%M") for m in range(24 * 60)]


def test_every_minute_of_lisbons_two_transition_days_of_2027_reads_the_same():
    asked = [
        (v, "Europe/Lisbon") for d in ("2027-03-28", "2027-10-31") for v in _every_minute_of(d)
    ]
    answers = _agree(asked)
    # The rule itself, not only the agreement: the repeated 01:30 is summer time (first)...
    assert answers["2027-10-31T01:30"]["iso"] == "2027-10-31T00:30:00Z"
    assert answers["2027-10-31T01:30"]["repeated"] is True
    assert answers["2027-10-31T01:30"]["offset"] == "UTC+01:00"
    assert answers["2027-10-31T02:30"]["repeated"] is False
    # ...and the skipped 01:30 is refused, saying why.
    assert answers["2027-03-28T01:30"] == {
        "error": "01:30 does not exist on 28 March 2027 in Europe/Lisbon: "
        "clocks go forward from 01:00 to 02:00"
    }


@settings(max_examples=6, deadline=None)
@given(
    days=st.lists(
        st.tuples(
            st.dates(datetime(2000, 1, 1).date(), datetime(2040, 12, 31).date()),
            st.sampled_from(ZONES),
        ),
        min_size=1,
        max_size=8,
    )
)
def test_random_days_in_several_zones_read_the_same(days):
    asked = [(v, zone) for day, zone in days for v in _every_minute_of(day.isoformat())[::11]]
    _agree(asked)
