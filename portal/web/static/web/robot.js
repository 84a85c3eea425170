// @ts-check
// Admin robot console: live status (pushed by the health check, polled while the stream is
// down; motion also from every drive command's answer), manual drive, emergency stop, service
// and holds, daily log.
(function () {
  "use strict";
  const root = document.getElementById("robot");
  if (!root) return;
  const base = `/api/v1/resources/${root.dataset.name}`;
  const feedback = document.getElementById("console-feedback");

  function say(text, isError) {
    feedback.hidden = false;
    feedback.textContent = text;
    feedback.className = "flash" + (isError ? " error" : "");
  }
  async function call(method, path, body) {
    const answer = await window.AmazingApi.api(method, base + path, body);
    if (!answer.ok) throw new Error(window.AmazingApi.explain(answer.data));
    return answer.data;
  }
  const set = (id, text) => { document.getElementById(id).textContent = text; };
  const fmt = (value, unit, digits) => (value === null || value === undefined ? "—" : `${Number(value).toFixed(digits)} ${unit}`);

  // The newest reading shown so far, by the base station's clock: a status read before a
  // drive command's answer but delivered after it does not move the numbers back.
  let shownClock = 0;
  const live = document.getElementById("hold-live");

  // Velocity, position and link, in the status panel and beside the hold-to-drive buttons;
  // from a status, a drive command's answer or the robot's stream (type "motion").
  function showMotion(robot, link, clock) {
    if (typeof clock === "number") {
      if (clock < shownClock) return;
      shownClock = clock;
    }
    robot = robot || {};
    link = link || {};
    const speed = robot.velocity_mps === null || robot.velocity_mps === undefined ? null : Number(robot.velocity_mps).toFixed(2);
    // A direction only while it moves: the telemetry keeps the last one at a stand.
    const velocity = speed === null ? "—" : `${speed} m/s ${Number(speed) > 0 ? robot.direction || "" : ""}`.trim();
    const position = fmt(robot.track_m, "m", 1);
    const linked = `${link.state || "?"}${link.loss_pct !== undefined && link.loss_pct !== null ? `, ${Number(link.loss_pct).toFixed(0)} % loss` : ""}`;
    set("st-velocity", velocity);
    set("st-position", position);
    set("st-link", linked);
    if (live) {
      set("hl-velocity", velocity);
      set("hl-position", position);
      set("hl-link", linked);
      live.dataset.readings = String(Number(live.dataset.readings || 0) + 1);
      live.dataset.velocityMps = String(robot.velocity_mps ?? "");
    }
  }
  document.addEventListener("robot:motion", (event) => {
    const motion = /** @type {CustomEvent} */ (event).detail;
    showMotion(motion.robot, motion.link, motion.clock);
  });

  function show(s, battery) {
    // Other parts of the page (roof.js) follow the same reading.
    document.dispatchEvent(new CustomEvent("robot:status", { detail: s }));
    showMotion(s.robot, s.link, s.clock);
    set("st-battery", fmt(battery.filtered_v, "V", 1) + (battery.low ? " (LOW)" : ""));
    set("st-run", s.current_run || "none");
    const estop = s.estop;
    const latched = Boolean(estop && estop.latched);
    set("st-estop", latched ? `LATCHED${estop.reason ? ": " + estop.reason : ""}` : "released");
    if (live) set("hl-estop", latched ? "LATCHED" : "released");
    // Latched: a banner that stays at the top of the page, and the button says so (pressing it
    // again latches again, harmlessly).
    document.getElementById("estop-latched").hidden = !latched;
    const button = document.getElementById("estop");
    button.classList.toggle("latched", latched);
    button.textContent = latched ? "STOPPED (latched)" : "EMERGENCY STOP";
    const host = s.host || {};
    set("st-cpu", fmt(host.cpu_temp_c, "°C", 0));
    set("st-disk", host.disk_free_bytes === null || host.disk_free_bytes === undefined ? "—" : fmt(host.disk_free_bytes / 1e6, "MB", 0));
  }

  async function refresh() {
    try {
      const data = await call("GET", "/robot/");
      show(data.status, data.battery);
      set("status-age", "updated " + new Date().toLocaleTimeString());
    } catch (error) {
      set("status-age", "base station unreachable: " + error.message);
    }
  }

  // The health check's reading, pushed every few seconds (portal/runs/services/health.py).
  function onStatus(health) {
    if (health.reachable && health.status) {
      show(health.status, health.status.battery || {});
      set("status-age", "updated " + new Date(health.checked_at_s * 1000).toLocaleTimeString());
    } else {
      set("status-age", "base station unreachable: " + (health.error || "no answer"));
    }
  }

  // Held by the health check, or back in service: the banner and the service form follow.
  function onHold(hold) {
    const banner = document.getElementById("robot-hold");
    banner.hidden = !hold.reason;
    set("hold-reason", hold.reason || "");
    set("hold-since", hold.held_at ? new Date(hold.held_at).toLocaleString() : "");
    set("service-state", hold.in_service ? "open" : "closed (out of service)");
    /** @type {HTMLInputElement} */ (document.querySelector("#service-form [name=enabled]")).value = hold.in_service ? "false" : "true";
    set("service-button", hold.in_service ? "Take out of service" : "Put back in service");
  }

  document.getElementById("estop").addEventListener("click", async () => {
    try { await call("POST", "/robot/stop/", { reason: "emergency stop from the console" }); say("Emergency stop latched."); }
    catch (error) { say("Stop failed: " + error.message, true); }
    refresh();
  });
  document.getElementById("drive-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    const f = /** @type {HTMLFormElement & {velocity_mps: HTMLInputElement, direction: HTMLSelectElement, ttl_s: HTMLInputElement, reason: HTMLInputElement, force: HTMLInputElement}} */ (event.target);
    try {
      await call("POST", "/robot/control/", {
        velocity_mps: Number(f.velocity_mps.value), direction: f.direction.value,
        ttl_s: Number(f.ttl_s.value), reason: f.reason.value, force: f.force.checked,
      });
      say(`Driving ${f.velocity_mps.value} m/s ${f.direction.value} for ${f.ttl_s.value} s.`);
    } catch (error) { say("Not sent: " + error.message, true); }
    refresh();
  });
  document.getElementById("release-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    const form = /** @type {HTMLFormElement & {reason: HTMLInputElement, reopen: HTMLInputElement}} */ (event.target);
    try {
      const answer = await call("POST", "/robot/release/", { reason: form.reason.value, reopen: form.reopen.checked });
      // Whether bookings are open is said with the release: a stop's hold outlives it.
      say(answer.in_service
        ? "Emergency stop released; bookings are open."
        : "Emergency stop released. Bookings stay closed" + (answer.hold_reason ? ` (held: ${answer.hold_reason})` : "") + ": put it back in service below when it is safe.");
      form.reason.value = "";
    }
    catch (error) { say("Not released: " + error.message, true); }
    refresh();
  });
  document.getElementById("service-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    const f = /** @type {HTMLFormElement & {enabled: HTMLInputElement, reason: HTMLInputElement}} */ (event.target);
    try {
      const resource = await call("POST", "/service/", { enabled: f.enabled.value === "true", reason: f.reason.value });
      onHold({ reason: resource.hold_reason, held_at: resource.held_at, in_service: resource.enabled && !resource.hold_reason });
      f.reason.value = "";
      say(resource.enabled ? "Back in service: bookings are open." : "Out of service: no new bookings.");
    } catch (error) { say("Not changed: " + error.message, true); }
  });
  // The log's instants (RFC 3339, to the microsecond, in UTC) as the testbed's wall clock
  // reads them, to the second: 2026-11-28 09:07:40.
  const logForm = /** @type {HTMLFormElement} */ (document.getElementById("log-form"));
  const logClock = new Intl.DateTimeFormat("sv-SE", {
    timeZone: logForm.dataset.zone || "UTC", year: "numeric", month: "2-digit", day: "2-digit",
    hour: "2-digit", minute: "2-digit", second: "2-digit", hour12: false,
  });
  function logTime(text) {
    const at = text ? new Date(text) : null;
    return at && !isNaN(at.getTime()) ? logClock.format(at) : text || "";
  }
  logForm.addEventListener("submit", async (event) => {
    // "Download CSV" submits the form itself: the browser saves the day's log.
    if (event.submitter && event.submitter.id === "log-download") return;
    event.preventDefault();
    const rows = /** @type {HTMLTableSectionElement} */ (document.getElementById("log-rows"));
    rows.textContent = "";
    try {
      const log = await call("GET", `/robot/logs/${/** @type {HTMLFormElement & {day: HTMLInputElement}} */ (event.target).day.value}/`);
      for (const entry of log.entries) {
        const tr = rows.insertRow();
        tr.insertCell().textContent = entry.user || "";
        tr.insertCell().textContent = entry.title || "";
        for (const key of ["start", "end"]) {
          const cell = tr.insertCell();
          cell.textContent = logTime(entry[key]);
          if (entry[key]) cell.title = entry[key];
        }
      }
      if (!log.entries.length) rows.insertRow().insertCell().textContent = "Nothing that day.";
    } catch (error) { say("Log not read: " + error.message, true); }
  });
  liveFollow(root.dataset.stream, {
    events: { status: onStatus, hold: onHold, motion: (motion) => showMotion(motion.robot, motion.link, motion.clock) },
    poll: refresh,
    pollMs: 2000,
    indicator: document.getElementById("live-status"),
  });
})();
