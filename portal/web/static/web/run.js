// @ts-check
// Run page: charts of velocity, position and battery; while the run is live, its state and
// new samples are pushed (live.js) and the charts and tables redrawn.
(function () {
  "use strict";
  const status = document.getElementById("run-status");
  if (!status) return;
  const { api, failure } = window.AmazingApi;

  // The y axis spans at least this much (its unit): a battery reading that flickers by one
  // step of the ADC (hundredths of a volt) is drawn as the small step it is, not stretched
  // over the whole chart as a barcode.
  const BATTERY_MIN_SPAN_V = 1.0;

  function lineChart(id, datasets, yTitle, minSpan = 0) {
    const canvas = document.getElementById(id);
    // The status keeps refreshing even if the chart library failed to load.
    if (!canvas || typeof Chart === "undefined") return null;
    const chart = new Chart(canvas, {
      type: "line",
      data: { datasets: datasets.map((d) => Object.assign({ data: [], pointRadius: 0 }, d)) },
      options: {
        animation: false, maintainAspectRatio: false, parsing: false, normalized: true,
        interaction: { mode: "nearest", intersect: false },
        scales: { x: { type: "linear", title: { display: true, text: "time since start (s)" } },
                  y: { title: { display: true, text: yTitle } } },
      },
    });
    chart.$minSpan = minSpan;
    return chart;
  }

  /** Centre the y axis on the data when the data spans less than ``chart.$minSpan``. */
  function spanAtLeast(chart) {
    const y = chart.options.scales.y;
    delete y.min;
    delete y.max;
    if (!chart.$minSpan) return;
    const values = chart.data.datasets.flatMap((d) => d.data.map((p) => p.y)).filter((v) => Number.isFinite(v));
    if (!values.length) return;
    const low = Math.min(...values);
    const high = Math.max(...values);
    if (high - low >= chart.$minSpan) return;
    const middle = (low + high) / 2;
    y.min = Math.floor((middle - chart.$minSpan / 2) * 10) / 10;
    y.max = Math.ceil((middle + chart.$minSpan / 2) * 10) / 10;
  }
  const charts = {
    velocity: lineChart("velocity-chart", [
      { key: "commanded_mps", label: "commanded (m/s, cw +)", borderWidth: 2, stepped: true },
      { key: "measured_mps", label: "measured (m/s, cw +)", borderWidth: 1.5 },
    ], "velocity (m/s)"),
    position: lineChart("position-chart", [
      { key: "track_m", label: "position along the rail, unwrapped (m, cw +)", borderWidth: 1.5 },
    ], "m from the rail's origin"),
    battery: lineChart("battery-chart", [
      // A reading holds until the next: drawn as steps, so a flicker shows as one.
      { key: "battery_v", label: "battery (V, median-filtered, held between readings)", borderWidth: 1.5, stepped: true },
    ], "V", BATTERY_MIN_SPAN_V),
  };

  function draw(series) {
    for (const chart of Object.values(charts)) {
      if (!chart) continue;
      for (const dataset of chart.data.datasets) {
        const s = series[dataset.key];
        dataset.data = s && Array.isArray(s.t) ? s.t.map((t, i) => ({ x: t, y: s.y[i] })) : [];
      }
      spanAtLeast(chart);
      chart.update();
    }
  }

  // Before the start: how long until it, every second, gone once the run has started.
  const countdown = document.getElementById("run-countdown");
  let countdownTimer = null;
  function tick() {
    const left = document.getElementById("run-countdown-left");
    const leftS = Math.round((Date.parse(countdown.dataset.start) - Date.now()) / 1000);
    if (leftS <= 0) { left.textContent = " · starting"; return; }
    const h = Math.floor(leftS / 3600);
    const m = Math.floor((leftS % 3600) / 60);
    const sec = leftS % 60;
    left.textContent = " · in " + (h ? `${h} h ${m} min` : m ? `${m} min ${sec} s` : `${sec} s`);
  }
  if (countdown) { tick(); countdownTimer = setInterval(tick, 1000); }

  function showState(state, label, reason) {
    if (countdown && !["scheduled", "staged"].includes(state)) {
      countdown.hidden = true;
      clearInterval(countdownTimer);
    }
    const el = document.getElementById("run-state");
    el.textContent = label;
    el.dataset.state = state;
    document.getElementById("run-reason").textContent = reason || "";
  }

  function showMissing(missing) {
    const box = document.getElementById("run-missing");
    const list = box.querySelector("ul");
    list.textContent = "";
    for (const text of missing || []) list.appendChild(document.createElement("li")).textContent = text;
    box.hidden = !(missing && missing.length);
  }

  let follow = null;
  let firstLoad = true;
  let loading = false;
  let again = false;

  function render(data) {
    // Other parts of the page (roof.js) follow the same answer.
    document.dispatchEvent(new CustomEvent("run:data", { detail: data }));
    draw(data.series);
    showState(data.state, data.state_label, data.reason);
    showMissing(data.missing);
    document.getElementById("sample-count").textContent = String(data.sample_count);
    // The server rendered the tables with the page; while samples arrive they are redrawn.
    if ((!firstLoad || data.live) && typeof data.analysis_html === "string") {
      document.getElementById("run-analysis").innerHTML = data.analysis_html;
    }
    firstLoad = false;
    // The rail length arrives with the first samples; the form's hint follows it.
    const form = document.getElementById("pass-form");
    if (form && data.rail_length_m && form.dataset.railLengthM !== String(data.rail_length_m)) {
      form.dataset.railLengthM = String(data.rail_length_m);
      document.getElementById("rail-hint").textContent =
        "(0 – " + data.rail_length_m.toFixed(1) + "; 0 is the rail's origin)";
    }
    const progress = document.getElementById("run-progress");
    progress.setAttribute("aria-busy", data.live ? "true" : "false");
    progress.textContent = data.live ? "updating…" : "";
    if (!data.live && follow) { follow.stop(); follow = null; }
  }

  // An answer has the run's shape, or it is not this page's (a proxy's page during a
  // restart, an error in another shape): such an answer is reported and the next read retries.
  function complete(data) {
    return data !== null && typeof data === "object" && typeof data.state === "string" &&
      data.series !== null && typeof data.series === "object" && typeof data.live === "boolean";
  }

  // A failed read is tried again, less and less often, until one succeeds: after the run's
  // last push (or on a finished run's page) nothing else would ever read it again.
  const RETRY_FIRST_MS = 1000;
  const RETRY_MAX_MS = 30000;
  let retryMs = RETRY_FIRST_MS;
  let retryTimer = null;
  function retryLater() {
    if (retryTimer !== null) return;
    retryTimer = setTimeout(() => { retryTimer = null; refresh(); }, retryMs);
    retryMs = Math.min(retryMs * 2, RETRY_MAX_MS);
  }

  // One read at a time; pushes that arrive meanwhile cause one more read after it. Whatever
  // the answer, the read ends in `finally`: no answer can leave the page stuck.
  async function refresh() {
    if (loading) { again = true; return; }
    loading = true;
    try {
      const result = await api("GET", status.dataset.url);
      if (!result.ok || result.data === null) throw new Error(failure(result));
      const data = result.data;
      if (!complete(data)) throw new Error("incomplete answer");
      render(data);
      retryMs = RETRY_FIRST_MS;
      if (retryTimer !== null) { clearTimeout(retryTimer); retryTimer = null; }
    } catch (error) {
      document.getElementById("run-progress").textContent = "(could not refresh: " + error.message + ")";
      retryLater();
    } finally {
      loading = false;
      if (again) { again = false; refresh(); }
    }
  }

  if (status.dataset.live === "1") {
    follow = liveFollow(status.dataset.stream, {
      events: {
        state: (event) => { showState(event.state, event.label, event.reason); refresh(); },
        samples: () => refresh(),
        // A measurement series changed (measurements.js reads it again).
        measurements: (event) => document.dispatchEvent(new CustomEvent("run:measurements", { detail: event })),
      },
      poll: refresh,
      pollMs: 3000,
      safetyMs: 15000,
      indicator: document.getElementById("live-status"),
    });
  } else {
    refresh();
  }
})();
