// @ts-check
// The booking calendar: Event Calendar's week, day, month and list views in the testbed's time
// zone, talking to the REST API. Like the timeline, it is given floating wall-clock times in
// the testbed's zone and gives them back the same way (wall_clock.js, docs/booking-pages.md).
(function () {
  "use strict";
  const el = document.getElementById("calendar");
  if (!el || typeof EventCalendar === "undefined") return;
  const zone = el.dataset.zone;
  const DateTime = luxon.DateTime;
  const filter = /** @type {HTMLSelectElement} */ (document.getElementById("resource-filter"));
  const dialog = /** @type {HTMLDialogElement} */ (document.getElementById("booking-dialog"));
  const form = /** @type {BookingForm & {resources: HTMLSelectElement}} */ (document.getElementById("booking-form"));
  const feedback = document.getElementById("booking-feedback");
  const eventDialog = /** @type {HTMLDialogElement} */ (document.getElementById("event-dialog"));
  let selected = null;

  const { api, explain, failure } = window.AmazingApi;
  const { typedWindow, floating, wall, offsetNow } = window.AmazingWallClock;

  // datetime-local values are wall-clock times in the testbed's zone, read by the portal's
  // rule for the nights the clocks change (wall_clock.js).
  const toLocalInput = (date) => wall(date, zone).toFormat("yyyy-LL-dd'T'HH:mm");

  // The booking the dialog holds; `times` says which occurrence a repeated time is, or why a
  // time cannot be booked.
  function bookingBody() {
    const resources = Array.from(form.resources.selectedOptions).map((o) => o.value);
    const times = typedWindow(form.start.value, form.end.value, zone);
    const body = { resources, start_at: times.start, end_at: times.end };
    if (form.experiment.value) body.experiment = Number(form.experiment.value);
    if (form.title.value) body.title = form.title.value;
    return { body, times };
  }

  let checkTimer = null;
  let checkSeq = 0; // the newest check: an older answer arriving after it is dropped
  async function liveCheck() {
    const seq = ++checkSeq;
    const { body, times } = bookingBody();
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
    // The same rules booking applies (time, service, program, maintenance, overlaps, leases on
    // the testbed scheduler, quota).
    const check = { resources: body.resources, start_at: body.start_at, end_at: body.end_at };
    if (body.experiment) check.experiment = body.experiment;
    const result = await api("POST", "/api/v1/reservations/check/", check);
    if (seq !== checkSeq) return;
    if (!result.ok) { feedback.textContent = explain(result.data); feedback.className = "error"; return; }
    const d = result.data;
    const problems = d.problems.flatMap((p) => (p.code === "quota" ? d.quota : [p.message]));
    let text = d.fits ? "Free, and within your quota." : problems.join(" ");
    if (d.fits && d.needs_approval) text += " An admin will confirm it.";
    if (d.notice) text += " " + d.notice;
    if (times.note) text += " " + times.note;
    feedback.textContent = text;
    feedback.className = d.fits ? "ok" : "error";
  }
  form.addEventListener("change", () => { clearTimeout(checkTimer); checkTimer = setTimeout(liveCheck, 150); });

  function openBooking(start, end) {
    selected = { start, end };
    form.reset();
    const shown = filter.value;
    for (const option of form.resources.options) option.selected = shown ? option.value === shown : false;
    form.start.value = toLocalInput(start);
    form.end.value = toLocalInput(end);
    feedback.textContent = "";
    dialog.showModal();
    liveCheck();
  }

  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    const button = /** @type {HTMLButtonElement} */ (document.getElementById("booking-confirm"));
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
      dialog.close();
      calendar.refetchEvents();
      flash(result.data.state === "requested" ? "Requested: an admin will confirm it." : "Booked.");
    } else {
      feedback.textContent = explain(result.data);
      feedback.className = "error";
    }
  });
  document.getElementById("booking-cancel").addEventListener("click", () => { dialog.close(); calendar.unselect(); });

  function flash(text) {
    let box = document.getElementById("calendar-flash");
    if (!box) {
      box = document.createElement("p");
      box.id = "calendar-flash";
      box.className = "flash";
      box.setAttribute("role", "status");
      el.parentNode.insertBefore(box, el);
    }
    box.textContent = text;
  }

  async function move(info) {
    const id = info.event.extendedProps.reservation;
    const times = { start_at: wall(info.event.start, zone).toISO(), end_at: wall(info.event.end, zone).toISO() };
    const result = await api("PATCH", `/api/v1/reservations/${id}/`, times);
    if (!result.ok) { info.revert(); flash("Not moved: " + explain(result.data)); } else { flash("Moved."); calendar.refetchEvents(); }
  }

  let current = null;
  function showEvent(info) {
    const props = info.event.extendedProps;
    if (props.kind !== "own" && props.kind !== "other") return;
    current = info.event;
    document.getElementById("event-title").textContent = info.event.title;
    const fmt = (d) => wall(d, zone).toFormat("yyyy-LL-dd HH:mm");
    document.getElementById("event-when").textContent = `${fmt(info.event.start)} – ${fmt(info.event.end)} (${zone})`;
    document.getElementById("event-state").textContent = "State: " + props.state;
    const run = /** @type {HTMLAnchorElement} */ (document.getElementById("event-run"));
    run.hidden = !props.url;
    run.href = props.url || "#";
    document.getElementById("event-cancel").hidden = !(props.state === "confirmed" || props.state === "requested");
    document.getElementById("event-feedback").textContent = "";
    eventDialog.showModal();
  }
  document.getElementById("event-close").addEventListener("click", () => eventDialog.close());
  document.getElementById("event-cancel").addEventListener("click", async () => {
    if (!current || !window.confirm("Cancel this booking?")) return;
    const result = await api("DELETE", `/api/v1/reservations/${current.extendedProps.reservation}/`, {});
    if (result.ok) { eventDialog.close(); calendar.refetchEvents(); flash("Cancelled."); }
    else document.getElementById("event-feedback").textContent = explain(result.data);
  });

  // Where a booking may be drawn, moved or stretched to, as the portal would allow it on the
  // shown resources: not over maintenance, not over another's booking; over one's own, yes
  // (the live check then says which resource collides).
  const overlaps = (a, b) => a.start < b.end && b.start < a.end;
  function freeFor(range, moving) {
    return !calendar.getEvents().some((other) => {
      if (moving && other.id === moving.id) return false;
      const kind = other.extendedProps.kind;
      const blocks = other.display === "background" || kind !== "own" || Boolean(moving);
      return blocks && overlaps(range, other);
    });
  }

  // The events of the shown range, their times floating in the testbed's zone.
  async function load(info) {
    const params = new URLSearchParams({
      start: DateTime.fromISO(info.startStr, { zone }).toISO(),
      end: DateTime.fromISO(info.endStr, { zone }).toISO(),
    });
    if (filter.value) params.set("resource", filter.value);
    const result = await api("GET", `${el.dataset.events}?${params}`);
    if (!result.ok || result.data === null) throw new Error(failure(result));
    return result.data.map((e) => Object.assign({}, e, { start: floating(e.start, zone), end: floating(e.end, zone) }));
  }

  // The hours scroll in the view's own box (app.css), which opens at the morning; an area that
  // scrolls must be reachable by keyboard (WCAG 2.1.1) even on a day without a booking to tab
  // to, so the box takes the focus itself, named by the calendar's title.
  function scrollArea() {
    const box = /** @type {HTMLElement | null} */ (el.querySelector(".ec-main"));
    if (!box || box.hasAttribute("tabindex")) return;
    box.tabIndex = 0;
    box.setAttribute("role", "region");
    box.setAttribute("aria-label", "Bookings");
  }

  const narrow = window.matchMedia("(max-width: 640px)").matches;
  const calendar = EventCalendar.create(el, {
    timeZone: offsetNow(zone),
    view: narrow ? "timeGridDay" : "timeGridWeek",
    headerToolbar: narrow
      ? { start: "prev,next", center: "title", end: "timeGridDay,listWeek" }
      : { start: "prev,next today", center: "title", end: "dayGridMonth,timeGridWeek,timeGridDay,listWeek" },
    // Event Calendar names both the week's grid and its list "week": the list is "list" here.
    buttonText: (text) => ({ ...text, listWeek: "list" }),
    firstDay: 1,
    nowIndicator: window.AmazingWallClock.browserShowsZone(zone),
    selectable: true,
    selectConstraint: (info) => freeFor(info, null),
    dragConstraint: (info) => freeFor(info.event, info.event),
    resizeConstraint: (info) => freeFor(info.event, info.event),
    editable: false,
    allDaySlot: false,
    slotDuration: "00:30",
    scrollTime: "08:00:00",
    height: narrow ? "520px" : "640px",
    slotLabelFormat: { hour: "2-digit", minute: "2-digit", hour12: false },
    eventTimeFormat: { hour: "2-digit", minute: "2-digit", hour12: false },
    dayHeaderFormat: { weekday: "short", day: "numeric", month: "short" },
    eventSources: [{ events: load }],
    // data-loading="false" once the shown range's bookings are in (tests and assistive
    // technology wait on it).
    loading: (busy) => { el.dataset.loading = busy ? "true" : "false"; el.setAttribute("aria-busy", String(busy)); },
    viewDidMount: scrollArea,
    eventDidMount: (info) => { info.el.dataset.kind = info.event.extendedProps.kind || ""; },
    select: (info) => openBooking(info.start, info.end),
    eventDrop: move,
    eventResize: move,
    eventClick: showEvent,
  });
  filter.addEventListener("change", () => calendar.refetchEvents());
  scrollArea();
  window.AmazingEventCalendar.keepPlain(el);
  el.dataset.ready = "true";

  // Robots held by their health check: the reason, as bookings of them would be refused.
  const holds = document.getElementById("robot-holds");
  function onHold(hold) {
    let item = /** @type {HTMLLIElement | null} */ (holds.querySelector(`li[data-resource="${CSS.escape(hold.resource)}"]`));
    if (!hold.reason) {
      if (item) item.remove();
    } else {
      if (!item) {
        item = holds.appendChild(document.createElement("li"));
        item.dataset.resource = hold.resource;
      }
      item.textContent = "";
      item.appendChild(document.createElement("strong")).textContent = hold.resource;
      const since = hold.held_at ? DateTime.fromISO(hold.held_at, { zone }).toFormat("yyyy-LL-dd HH:mm") : "now";
      item.append(` is out of service since ${since}: ${hold.reason}`);
    }
    holds.hidden = !holds.querySelector("li");
    if (dialog.open) liveCheck();
  }
  // Others' bookings and maintenance windows appear without a reload (several changes in a
  // burst cause one read).
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
