// @ts-check
// Hold-to-drive: while a button or key is held the console repeats a short-lived manual drive
// command (every data-repeat-ms, each valid data-ttl-s on the base station); letting go,
// hiding or leaving the page, or losing focus sends velocity 0 at once. If that stop is lost
// too, the last command expires on the base station within its TTL and the robot ramps down.
(function () {
  "use strict";
  const box = document.getElementById("hold-drive");
  const root = document.getElementById("robot");
  if (!box || !root) return;
  const url = `/api/v1/resources/${root.dataset.name}/robot/control/`;
  const { api, failure } = window.AmazingApi;
  const ttlS = Number(box.dataset.ttlS);
  const repeatMs = Number(box.dataset.repeatMs);
  const state = document.getElementById("hold-state");
  const velocity = /** @type {HTMLInputElement} */ (document.getElementById("held-velocity"));
  const reason = /** @type {HTMLInputElement} */ (document.getElementById("held-reason"));
  const force = /** @type {HTMLInputElement} */ (document.getElementById("held-force"));
  const buttons = Array.from(/** @type {NodeListOf<HTMLButtonElement>} */ (box.querySelectorAll("button.hold")));

  let held = null; // {direction, timer, source}
  let inFlight = false;
  // A repeat already on its way when the hold ends can reach the base station after the stop
  // and drive again until its TTL: the stop goes once more when that repeat is answered.
  let stopAgain = null; // {body, keepalive}

  function say(text, kind) {
    state.textContent = text;
    state.dataset.state = kind;
  }

  // Each answer carries the robot's motion as the base station read it: the console shows it
  // beside the buttons (web/robot.js), so a hold is followed at its repeat rate.
  function motion(data) {
    if (data && data.robot) {
      document.dispatchEvent(new CustomEvent("robot:motion", { detail: { robot: data.robot, link: data.link, clock: data.clock } }));
    }
  }

  // Resolves to api.js's {ok, status, data}, never rejects.
  async function send(body, keepalive) {
    // Outlives the page: the stop still goes when the tab is being closed.
    const result = await api("POST", url, body, { keepalive: Boolean(keepalive) });
    if (result.ok) motion(result.data);
    return result;
  }

  // After letting go the robot ramps down with no command to answer: its status is read twice
  // as often as the hold repeated until it stands still (or FOLLOW_MS passed, or another hold
  // began), so that the slowing shows as promptly as the start did.
  const FOLLOW_MS = 10000;
  let following = 0;
  async function follow() {
    const mine = ++following;
    const until = Date.now() + FOLLOW_MS;
    while (mine === following && !held && Date.now() < until) {
      await new Promise((done) => setTimeout(done, repeatMs / 2));
      if (mine !== following || held) return;
      const result = await api("GET", `/api/v1/resources/${root.dataset.name}/robot/`);
      if (!result.ok) return;
      const status = result.data.status || {};
      motion(status);
      if (!status.robot || !status.robot.velocity_mps) return;
    }
  }

  async function tick() {
    if (!held || inFlight) return;
    inFlight = true;
    const direction = held.direction;
    try {
      const result = await send({
        velocity_mps: Number(velocity.value), direction, ttl_s: ttlS,
        reason: reason.value, force: force.checked, hold: true,
      });
      if (!result.ok) {
        // Refused, or no answer (nothing reached the base station: the last command expires
        // there by itself).
        const data = result.data;
        release(false);
        say("Not driving: " + (data ? data.detail || JSON.stringify(data.fields || data) : failure(result)), "error");
        return;
      }
      if (held && held.direction === direction) {
        say(`Driving ${Number(velocity.value).toFixed(2)} m/s ${direction === "cw" ? "clockwise" : "counter-clockwise"} while held.`, "driving");
      }
    } finally {
      inFlight = false;
      const stop = stopAgain;
      stopAgain = null;
      if (stop && !held) send(stop.body, stop.keepalive); // if lost too, the TTL stops the robot
    }
  }

  function press(direction, source) {
    if (held) return;
    if (!reason.value.trim()) {
      say("Not driving: say why you drive the robot by hand (Reason).", "error");
      reason.focus();
      return;
    }
    following++; // a follow-up still reading the last hold's ramp stops here
    held = { direction, source, timer: setInterval(tick, repeatMs) };
    for (const button of buttons) button.setAttribute("aria-pressed", String(button.dataset.direction === direction));
    tick();
  }

  // Velocity 0 now (not waiting for the TTL), unless nothing was being driven.
  function release(sendStop, keepalive) {
    if (!held) return;
    const direction = held.direction;
    clearInterval(held.timer);
    held = null;
    for (const button of buttons) button.setAttribute("aria-pressed", "false");
    say("Stopped.", "idle");
    if (sendStop) {
      const body = { velocity_mps: 0, direction, ttl_s: ttlS, reason: reason.value || "hold released", force: false, hold: true };
      send(body, keepalive); // if lost, the command's TTL stops the robot
      if (inFlight) stopAgain = { body, keepalive };
      if (!keepalive) follow();
    }
  }

  for (const button of buttons) {
    button.setAttribute("aria-pressed", "false");
    button.addEventListener("pointerdown", (event) => {
      event.preventDefault();
      button.setPointerCapture(event.pointerId);
      press(button.dataset.direction, "pointer");
    });
    for (const type of ["pointerup", "pointercancel", "lostpointercapture"]) {
      button.addEventListener(type, () => { if (held && held.source === "pointer") release(true); });
    }
    // Enter or Space on a focused button holds too (keyboard users without the shortcuts).
    button.addEventListener("keydown", (event) => {
      if ((event.key === "Enter" || event.key === " ") && !event.repeat) { event.preventDefault(); press(button.dataset.direction, "key:" + event.key); }
    });
    button.addEventListener("keyup", (event) => {
      if (held && held.source === "key:" + event.key) release(true);
    });
    button.addEventListener("contextmenu", (event) => event.preventDefault());
  }

  const KEYS = { ArrowRight: "cw", d: "cw", D: "cw", ArrowLeft: "ccw", a: "ccw", A: "ccw" };
  const typing = (target) => target instanceof HTMLElement && (target.isContentEditable || ["INPUT", "SELECT", "TEXTAREA"].includes(target.tagName));
  document.addEventListener("keydown", (event) => {
    if (event.key === "Escape") {
      event.preventDefault();
      release(false);
      document.getElementById("estop").click();
      return;
    }
    if (typing(event.target) || event.target instanceof HTMLButtonElement) return;
    if (event.key === " ") { event.preventDefault(); release(true); return; }
    const direction = KEYS[event.key];
    if (direction && !event.repeat && !event.ctrlKey && !event.metaKey && !event.altKey) {
      event.preventDefault();
      press(direction, "key:" + event.key);
    }
  });
  document.addEventListener("keyup", (event) => {
    if (held && held.source === "key:" + event.key) release(true);
  });
  // A page that loses the user stops the robot.
  window.addEventListener("blur", () => release(true));
  document.addEventListener("visibilitychange", () => { if (document.hidden) release(true, true); });
  window.addEventListener("pagehide", () => release(true, true));
})();
