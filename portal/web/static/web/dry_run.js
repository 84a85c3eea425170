// @ts-check
// A dry run that waits or runs: its place in line and state, read every second; once it has
// ended the page is loaded again, with the charts and statistics of the run page.
(function () {
  "use strict";
  const status = document.getElementById("run-status");
  if (!status || status.dataset.waiting !== "1") return;
  const state = document.getElementById("run-state");
  const place = document.getElementById("dry-run-place");
  const progress = document.getElementById("run-progress");
  const POLL_MS = 1000;
  const { api, failure } = window.AmazingApi;

  async function poll() {
    try {
      const result = await api("GET", status.dataset.url);
      if (!result.ok || result.data === null) throw new Error(failure(result));
      const data = result.data;
      if (!data.live) { window.location.reload(); return; }
      state.textContent = data.state_label;
      state.dataset.state = data.state;
      place.textContent = data.place ? `Place in line: ${data.place}.` : "";
      progress.textContent = "";
    } catch (error) {
      progress.textContent = "(could not refresh: " + error.message + ")";
    }
    setTimeout(poll, POLL_MS);
  }
  setTimeout(poll, POLL_MS);
})();
