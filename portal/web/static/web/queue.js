// @ts-check
// The queue page: the requests' places and estimates read again whenever the calendar
// changes (its live stream), and every 15 s besides, since a request queued or withdrawn
// moves the places without touching the calendar.
(function () {
  "use strict";
  const box = document.getElementById("queue-requests-box");
  if (!box || !box.dataset.part || !box.dataset.stream) return;
  const part = box.dataset.part;
  let reading = false;
  async function refresh() {
    if (reading || !box) return;
    reading = true;
    try {
      const answer = await fetch(part, { credentials: "same-origin", headers: { Accept: "text/html" } });
      if (answer.ok) box.innerHTML = await answer.text();
    } catch (error) {
      // Offline for a moment: the next change or poll reads again.
    } finally {
      reading = false;
    }
  }
  window.liveFollow(box.dataset.stream, {
    events: { changed: refresh },
    poll: refresh,
    pollMs: 15000,
    safetyMs: 15000,
    indicator: document.getElementById("live-status"),
  });
})();
