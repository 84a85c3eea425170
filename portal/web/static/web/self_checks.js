// @ts-check
// A robot's self-checks page: one small chart per figure, each check a point in time order,
// the baseline a dashed line (json_script "trend-data").
(function () {
  const data = document.getElementById("trend-data");
  if (!data || typeof Chart === "undefined") return;
  /** @type {{at: string[], figures: Record<string, (number|null)[]>, labels: Record<string, string>, baseline: Record<string, number|null>|null}} */
  const trend = JSON.parse(data.textContent || "{}");
  const when = trend.at.map((iso) => new Date(iso).toLocaleString([], { dateStyle: "short", timeStyle: "short" }));
  for (const [key, values] of Object.entries(trend.figures)) {
    const canvas = document.getElementById(`trend-${key}`);
    if (!(canvas instanceof HTMLCanvasElement)) continue;
    const datasets = [{ label: trend.labels[key], data: values, spanGaps: true, pointRadius: 3 }];
    const base = trend.baseline ? trend.baseline[key] : null;
    if (base !== null && base !== undefined) {
      datasets.push({ label: "baseline", data: values.map(() => base), spanGaps: true, pointRadius: 0, borderDash: [6, 4] });
    }
    new Chart(canvas, {
      type: "line",
      data: { labels: when, datasets },
      options: { maintainAspectRatio: false, animation: false, plugins: { legend: { display: true } } },
    });
  }
})();
