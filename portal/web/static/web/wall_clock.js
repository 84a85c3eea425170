// @ts-check
// Wall-clock times typed in the testbed's zone, read as instants by the portal's one rule
// (core/wall_clock.py, which the Book page's form uses): a time the clocks pass twice is its
// first occurrence (the earlier instant, still summer time); a time they skip is refused, with
// a message that says why. luxon alone takes the later occurrence and moves a skipped time on
// by the jump, silently. tests/web/test_wall_clock_js.py holds the two to the same answers.
window.AmazingWallClock = (function () {
  "use strict";
  const WALL = "yyyy-LL-dd'T'HH:mm";

  // The wall-clock times either side of the jump that skips `asUtc` (the typed time read as
  // if in UTC), as core/wall_clock.py _gap_around: the change lies between the typed time read
  // with the offset before and with the offset after.
  function gapAround(asUtc, zone, before, after) {
    const { DateTime } = luxon;
    let early = asUtc.minus({ minutes: after }).toMillis();
    let late = asUtc.minus({ minutes: before }).toMillis();
    while (late - early > 1000) {
      const middle = early + Math.floor((late - early) / 2);
      if (DateTime.fromMillis(middle, { zone }).offset === before) early = middle;
      else late = middle;
    }
    const change = DateTime.fromMillis(Math.floor(late / 1000) * 1000, { zone: "utc" });
    return [change.plus({ minutes: before }), change.plus({ minutes: after })];
  }

  // {iso, offset, repeated} for a datetime-local value ("2027-10-31T01:30"), or {error}.
  // `offset` is "UTC+01:00"; `repeated` says the clocks pass this time twice that night.
  function localInstant(value, zone) {
    const { DateTime } = luxon;
    const typed = (value || "").slice(0, 16);
    const asUtc = typed ? DateTime.fromFormat(typed, WALL, { zone: "utc" }) : null;
    if (!asUtc || !asUtc.isValid) return { error: "Give a date and a time." };
    // The offsets in force a day before and a day after: the typed time read with each is an
    // occurrence when the zone's clock shows it then. None: skipped; two: passed twice.
    const before = asUtc.minus({ days: 1 }).setZone(zone).offset;
    const after = asUtc.plus({ days: 1 }).setZone(zone).offset;
    const occurrences = [...new Set([before, after])]
      .map((offset) => asUtc.minus({ minutes: offset }).setZone(zone))
      .filter((instant) => instant.toFormat(WALL) === typed)
      .sort((a, b) => a.toMillis() - b.toMillis());
    if (!occurrences.length) {
      const [from, to] = gapAround(asUtc, zone, before, after);
      return {
        error: `${asUtc.toFormat("HH:mm")} does not exist on ${asUtc.toFormat("d LLLL yyyy")} in ${zone}: ` +
          `clocks go forward from ${from.toFormat("HH:mm")} to ${to.toFormat("HH:mm")}`,
      };
    }
    const first = occurrences[0];
    return {
      iso: first.toUTC().toISO({ suppressMilliseconds: true }),
      offset: `UTC${first.toFormat("ZZ")}`,
      repeated: occurrences.length > 1,
    };
  }

  // The typed start and end of a booking dialog: {start, end} as ISO instants, a `note` saying
  // which occurrence a repeated time is, or an `error` for a time that does not exist.
  function typedWindow(startValue, endValue, zone) {
    const start = localInstant(startValue, zone);
    const end = localInstant(endValue, zone);
    const error = start.error || end.error;
    if (error) return { error };
    const notes = [];
    for (const [value, read] of [[startValue, start], [endValue, end]]) {
      if (read.repeated) notes.push(`${value.slice(11, 16)} is the first of the two that night (${read.offset}).`);
    }
    return { start: start.iso, end: end.iso, note: notes.join(" ") };
  }

  // Event Calendar knows UTC offsets, not zones: the calendar and the timeline give it
  // "floating" wall-clock times in the testbed's zone and read its dates back the same way
  // (docs/booking-pages.md "Times"), converting with luxon here, at the edges.
  const FLOATING = "yyyy-LL-dd'T'HH:mm:ss";

  // An instant (ISO 8601 with its offset) as the testbed's wall-clock time, without an offset.
  function floating(iso, zone) {
    return luxon.DateTime.fromISO(iso, { zone }).toFormat(FLOATING);
  }

  // An Event Calendar date, which carries the testbed's wall-clock time in the browser's
  // fields, as the instant in the testbed's zone.
  function wall(date, zone) {
    return luxon.DateTime.fromObject({
      year: date.getFullYear(), month: date.getMonth() + 1, day: date.getDate(),
      hour: date.getHours(), minute: date.getMinutes(), second: date.getSeconds(),
    }, { zone });
  }

  // The offset in force now, which the calendars are told to draw in.
  function offsetNow(zone) {
    return luxon.DateTime.now().setZone(zone).toFormat("ZZ");
  }

  // Event Calendar draws its red "now" line by the browser's clock, not by the offset it is
  // told: the line is shown only where the two agree, rather than at the wrong hour.
  function browserShowsZone(zone) {
    return luxon.DateTime.local().offset === luxon.DateTime.now().setZone(zone).offset;
  }

  return { localInstant, typedWindow, floating, wall, offsetNow, browserShowsZone };
})();
