// @ts-check
// The resource timeline: Event Calendar's resource timeline, one row per robot and fixed node.
// A drag across several rows books them together; the live check answers while dragging.
//
// Times: Event Calendar knows UTC offsets only, not zones, so everything it is given and gives
// back is wall-clock time in the testbed's zone ("floating"), converted at the edges
// (wall_clock.js), as on the calendar page.
(function () {
  "use strict";
  const el = document.getElementById("timeline");
  if (!el || typeof EventCalendar === "undefined") return;
  const zone = el.dataset.zone;
  const DateTime = luxon.DateTime;
  const rows = JSON.parse(document.getElementById("timeline-rows").textContent);
  const leaves = rows.flatMap((group) => group.children);
  const order = leaves.map((r) => r.id); // rows top to bottom: a drag takes those between
  const byId = new Map(leaves.map((r) => [r.id, r]));
  const checkLine = document.getElementById("timeline-check");
  const dialog = /** @type {HTMLDialogElement} */ (document.getElementById("timeline-dialog"));
  const form = /** @type {BookingForm} */ (document.getElementById("timeline-form"));
  const feedback = document.getElementById("timeline-feedback");
  // The grid's columns (half hours) and the minutes a drag snaps to (TIMELINE_SNAP_MIN).
  const SLOT_MIN = 30;
  const SNAP_MIN = Number(el.dataset.snapMin) || 5;

  const { api, explain, failure } = window.AmazingApi;
  const { typedWindow, offsetNow } = window.AmazingWallClock;
  const wall = (d) => window.AmazingWallClock.wall(d, zone);
  const floating = (iso) => window.AmazingWallClock.floating(iso, zone);
  const toLocalInput = (dt) => dt.toFormat("yyyy-LL-dd'T'HH:mm");
  const shown = (dt) => dt.toFormat("ccc d LLL HH:mm");

  // --- What the rows hold --------------------------------------------------------------------
  function rowsOf(names) {
    return names.includes("all") ? order.slice() : names.filter((n) => byId.has(n));
  }
  function toEvent(e) {
    const props = e.extendedProps;
    return {
      id: e.id,
      title: e.title,
      start: floating(e.start),
      end: floating(e.end),
      resourceIds: rowsOf(props.resources),
      editable: false,
      classNames: [`timeline-${props.kind}`],
      extendedProps: props,
    };
  }
  function holdEvents(range) {
    // A robot held by its health check stays out of service until an admin releases it.
    return leaves.filter((r) => r.extendedProps.hold_reason).map((r) => ({
      id: `hold-${r.id}`,
      title: `Out of service: ${r.extendedProps.hold_reason}`,
      start: r.extendedProps.held_at ? floating(r.extendedProps.held_at) : range.start,
      end: range.end,
      resourceIds: [r.id],
      editable: false,
      classNames: ["timeline-hold"],
      extendedProps: { kind: "hold", resources: [r.id] },
    }));
  }
  async function load(info) {
    const range = { start: DateTime.fromISO(info.startStr, { zone }), end: DateTime.fromISO(info.endStr, { zone }) };
    const params = new URLSearchParams({ start: range.start.toISO(), end: range.end.toISO() });
    const result = await api("GET", `${el.dataset.events}?${params}`);
    if (!result.ok || result.data === null) throw new Error(failure(result));
    return result.data.map(toEvent).concat(holdEvents({ start: info.startStr, end: info.endStr }));
  }

  // --- Dragging across rows ------------------------------------------------------------------
  const labels = new Map();
  let drag = null; // {first, last, start, end}: rows and wall-clock times under the pointer
  let checkTimer = null;
  let checkSeq = 0;

  function pointAt(x, y) {
    const info = calendar.dateFromPoint(x, y);
    if (!info || !info.resource || !byId.has(String(info.resource.id))) return null;
    return { row: String(info.resource.id), at: timeAt(x) || wall(info.date) };
  }
  /** The wall-clock time under ``x``, read from the header's labels: Event Calendar's own
   * answer within a column is tens of pixels off, minutes where a drag snaps to five. */
  function timeAt(x) {
    const labels = Array.from(el.querySelectorAll(".ec-slots time[datetime]"));
    for (let i = 0; i < labels.length; i++) {
      const box = labels[i].parentElement.getBoundingClientRect();
      if (x < box.left || x >= box.right || box.width <= 0) continue;
      const from = DateTime.fromISO(labels[i].getAttribute("datetime"), { zone });
      const next = labels[i + 1] && DateTime.fromISO(labels[i + 1].getAttribute("datetime"), { zone });
      const spanMin = next && next > from ? next.diff(from, "minutes").minutes : 60;
      return from.plus({ minutes: ((x - box.left) / box.width) * spanMin });
    }
    return null;
  }
  function dragRows() {
    const a = order.indexOf(drag.first);
    const b = order.indexOf(drag.last);
    return order.slice(Math.min(a, b), Math.max(a, b) + 1);
  }
  function snapFloor(dt) { return dt.set({ minute: dt.minute - (dt.minute % SNAP_MIN), second: 0, millisecond: 0 }); }
  function dragTimes() {
    const a = snapFloor(drag.from);
    const b = snapFloor(drag.to);
    return a <= b ? [a, b.plus({ minutes: SNAP_MIN })] : [b, a.plus({ minutes: SNAP_MIN })];
  }
  /** The window to offer for a drag: a start already past moves to the next snap after now
   * (the end with it when it would come first), and the dialog says so. */
  function fromNow(start, end) {
    const now = DateTime.now().setZone(zone);
    if (start >= now) return { start, end, note: "" };
    const next = snapFloor(now).plus({ minutes: SNAP_MIN });
    const later = end > next ? end : next.plus({ minutes: SNAP_MIN });
    return { start: next, end: later, note: `The start was in the past: moved to ${next.toFormat("HH:mm")}.` };
  }
  function markRows(names) {
    for (const [name, label] of labels) label.classList.toggle("timeline-picked", names.includes(name));
  }

  // The same rules booking applies, asked again whenever the dragged rows or times change.
  async function check(resources, start, end, experiment, target, note = "") {
    const seq = ++checkSeq;
    const body = { resources, start_at: start.toISO(), end_at: end.toISO() };
    if (experiment) body.experiment = experiment;
    const result = await api("POST", "/api/v1/reservations/check/", body);
    if (seq !== checkSeq) return; // a newer drag has asked since
    let text;
    let fits = false;
    if (!result.ok) text = explain(result.data);
    else {
      const d = result.data;
      fits = d.fits;
      const problems = d.problems.flatMap((p) => (p.code === "quota" ? d.quota : [p.message]));
      text = d.fits ? "Free, and within your quota." : problems.join(" ");
      if (d.fits && d.needs_approval) text += " An admin will confirm it.";
      if (d.notice) text += " " + d.notice;
      if (note) text += " " + note;
    }
    target.textContent = target === checkLine ? `${resources.join(", ")} · ${shown(start)}–${end.toFormat("HH:mm")}: ${text}` : text;
    target.className = (target === checkLine ? "timeline-check " : "") + (fits ? "ok" : "error");
    target.dataset.fits = String(fits);
  }
  function checkDrag() {
    const resources = dragRows();
    const [start, end] = dragTimes();
    markRows(resources);
    clearTimeout(checkTimer);
    // A robot is booked with its experiment: while dragging, say only what else is wrong.
    checkTimer = setTimeout(() => check(resources, start, end, null, checkLine), 200);
  }

  el.addEventListener("pointerdown", (event) => {
    const point = event.button === 0 ? pointAt(event.clientX, event.clientY) : null;
    drag = point && { first: point.row, last: point.row, from: point.at, to: point.at };
  });
  document.addEventListener("pointermove", (event) => {
    if (!drag || !(event.buttons & 1)) return;
    const point = pointAt(event.clientX, event.clientY);
    if (!point) return;
    const [oldStart, oldEnd] = dragTimes();
    const oldLast = drag.last;
    drag.last = point.row;
    drag.to = point.at;
    const [start, end] = dragTimes();
    if (oldLast !== drag.last || +oldStart !== +start || +oldEnd !== +end) checkDrag();
  });

  // --- The booking dialog --------------------------------------------------------------------
  // The booking the dialog holds; `times` says which occurrence a repeated time is, or why a
  // time cannot be booked (wall_clock.js: the portal's rule for the nights the clocks change).
  function bookingBody() {
    const resources = Array.from(/** @type {NodeListOf<HTMLInputElement>} */ (form.querySelectorAll("input[name=resources]:checked"))).map((i) => i.value);
    const times = typedWindow(form.start.value, form.end.value, zone);
    const body = { resources, start_at: times.start, end_at: times.end };
    if (form.experiment.value) body.experiment = Number(form.experiment.value);
    if (form.title.value) body.title = form.title.value;
    return { body, times };
  }
  let dialogTimer = null;
  function checkDialog() {
    const { body, times } = bookingBody();
    clearTimeout(dialogTimer);
    if (times.error || !body.resources.length) checkSeq += 1; // an answer on its way is stale
    if (times.error) {
      feedback.textContent = times.error + ".";
      feedback.className = "error";
      return;
    }
    if (!body.resources.length) {
      feedback.textContent = "Choose at least one resource.";
      feedback.className = "";
      return;
    }
    dialogTimer = setTimeout(() => check(
      body.resources, DateTime.fromISO(body.start_at, { zone }), DateTime.fromISO(body.end_at, { zone }),
      body.experiment, feedback, [moved, times.note].filter(Boolean).join(" "),
    ), 150);
  }
  form.addEventListener("change", checkDialog);

  let moved = ""; // what openBooking changed in the dragged window, said with the check
  function openBooking(resources, draggedStart, draggedEnd) {
    // The drag's own check, if still to come, would make the dialog's answer stale.
    clearTimeout(checkTimer);
    const { start, end, note } = fromNow(draggedStart, draggedEnd);
    moved = note;
    form.reset();
    for (const box of /** @type {NodeListOf<HTMLInputElement>} */ (form.querySelectorAll("input[name=resources]"))) box.checked = resources.includes(box.value);
    form.start.value = toLocalInput(start);
    form.end.value = toLocalInput(end);
    feedback.textContent = "";
    dialog.showModal();
    checkDialog();
  }
  function closeBooking() {
    moved = "";
    dialog.close();
    calendar.unselect();
    markRows([]);
    checkSeq += 1; // an answer still on its way is for a drag that is over
    checkLine.textContent = "";
    checkLine.className = "timeline-check";
  }
  document.getElementById("timeline-close").addEventListener("click", closeBooking);

  function flash(text, link = null) {
    let box = document.getElementById("timeline-flash");
    if (!box) {
      box = document.createElement("p");
      box.id = "timeline-flash";
      box.className = "flash";
      box.setAttribute("role", "status");
      el.parentNode.insertBefore(box, el);
    }
    box.textContent = text;
    if (link) {
      box.append(" ");
      const a = box.appendChild(document.createElement("a"));
      a.href = link.href;
      a.textContent = link.text;
    }
  }

  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    const button = /** @type {HTMLButtonElement} */ (document.getElementById("timeline-confirm"));
    button.setAttribute("aria-busy", "true");
    button.disabled = true;
    const { body, times } = bookingBody();
    if (times.error) {
      feedback.textContent = times.error + ".";
      feedback.className = "error";
      button.removeAttribute("aria-busy");
      button.disabled = false;
      return;
    }
    const key = (crypto.randomUUID && crypto.randomUUID()) || String(Date.now()) + Math.random();
    const result = await api("POST", "/api/v1/reservations/", body, { headers: { "X-Idempotency-Key": key } });
    button.removeAttribute("aria-busy");
    button.disabled = false;
    if (result.ok) {
      closeBooking();
      calendar.refetchEvents();
      const run = result.data.run;
      flash(
        result.data.state === "requested" ? "Requested: an admin will confirm it." : "Booked.",
        run ? { href: `/runs/${run.id}/`, text: `Its run starts ${shown(DateTime.fromISO(result.data.start_at, { zone }))}: open it.` } : null,
      );
    } else {
      feedback.textContent = explain(result.data);
      feedback.className = "error";
    }
  });

  // --- The calendar --------------------------------------------------------------------------
  const narrow = window.matchMedia("(max-width: 640px)").matches;
  const calendar = EventCalendar.create(el, {
    view: "resourceTimelineDay",
    // The offset in force now; the events' times are floating wall-clock times (see above).
    timeZone: offsetNow(zone),
    headerToolbar: { start: "prev,next today", center: "title", end: narrow ? "" : "resourceTimelineDay,resourceTimelineWeek" },
    buttonText: (texts) => Object.assign({}, texts, { today: "Today", resourceTimelineDay: "Day", resourceTimelineWeek: "Week" }),
    resources: rows,
    firstDay: 1,
    nowIndicator: window.AmazingWallClock.browserShowsZone(zone),
    selectable: true,
    editable: false,
    slotDuration: { minutes: SLOT_MIN },
    snapDuration: { minutes: SNAP_MIN },
    slotWidth: narrow ? 36 : 44,
    // Opened on now: an hour before it at the left edge.
    scrollTime: DateTime.now().setZone(zone).minus({ hours: 1 }).toFormat("HH:00:00"),
    height: "auto",
    slotLabelFormat: { hour: "2-digit", minute: "2-digit", hour12: false },
    eventTimeFormat: { hour: "2-digit", minute: "2-digit", hour12: false },
    eventSources: [{ events: load }],
    // data-loading="false" once the shown range's entries are in (tests and assistive
    // technology wait on it).
    loading: (busy) => { el.dataset.loading = busy ? "true" : "false"; el.setAttribute("aria-busy", String(busy)); },
    resourceLabelDidMount: (info) => {
      const id = String(info.resource.id);
      if (!byId.has(id)) return;
      labels.set(id, info.el);
      info.el.dataset.resource = id;
      const hold = byId.get(id).extendedProps.hold_reason;
      info.el.classList.toggle("timeline-held", Boolean(hold));
      if (hold) info.el.title = `Out of service: ${hold}`;
    },
    eventDidMount: (info) => {
      info.el.title = info.event.title;
      info.el.dataset.kind = info.event.extendedProps.kind || "";
    },
    eventClick: (info) => {
      if (info.event.extendedProps.url) window.location.assign(info.event.extendedProps.url);
    },
    select: (info) => {
      // Event Calendar selects time in one row; the rows are the ones the drag crossed.
      const resources = drag ? dragRows() : [String(info.resource.id)];
      const [start, end] = drag ? dragTimes() : [wall(info.start), wall(info.end)];
      drag = null;
      openBooking(resources, start, end);
    },
  });
  // Its grid roles go (event_calendar.js): the rows are named in text, the bookings are links.
  window.AmazingEventCalendar.keepPlain(el);
  el.dataset.ready = "true";

  // Holds and others' bookings appear without a reload (several changes in a burst cause one read).
  function onHold(hold) {
    const row = byId.get(hold.resource);
    if (!row) return;
    row.extendedProps.hold_reason = hold.reason || "";
    row.extendedProps.held_at = hold.reason ? hold.held_at : null;
    const label = labels.get(hold.resource);
    if (label) {
      label.classList.toggle("timeline-held", Boolean(hold.reason));
      label.title = hold.reason ? `Out of service: ${hold.reason}` : "";
    }
    calendar.refetchEvents();
    if (dialog.open) checkDialog();
  }
  let refetchTimer = null;
  function onChanged() {
    clearTimeout(refetchTimer);
    refetchTimer = setTimeout(() => calendar.refetchEvents(), 300);
  }
  liveFollow(el.dataset.stream, {
    events: { changed: onChanged, hold: onHold },
    poll: () => calendar.refetchEvents(),
    pollMs: 30000,
    indicator: document.getElementById("live-status"),
  });
})();
