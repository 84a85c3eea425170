// @ts-check
// The usage page's chart, drawn from the table's data (json_script "usage-data").
(function () {
  const data = document.getElementById("usage-data");
  if (!data || typeof Chart === "undefined") return;
  const rows = JSON.parse(data.textContent);
  new Chart(document.getElementById("usage-chart"), {
    type: "bar",
    data: { labels: rows.map((r) => r[0]), datasets: [{ label: "hours", data: rows.map((r) => r[1]) }] },
    options: { maintainAspectRatio: false, animation: false, indexAxis: rows.length > 8 ? "y" : "x" },
  });
})();
