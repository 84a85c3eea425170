// @ts-check
// Add and remove segment rows of the experiment form; the form also works without this.
(function () {
  "use strict";
  const body = /** @type {HTMLTableSectionElement | null} */ (document.querySelector("#segments tbody"));
  const add = document.getElementById("add-segment");
  if (!body || !add) return;
  function renumber() {
    body.querySelectorAll("tr").forEach((row, i) => { row.querySelector(".index").textContent = String(i); });
  }
  add.addEventListener("click", () => {
    const row = /** @type {HTMLTableRowElement} */ (body.querySelector("tr").cloneNode(true));
    row.querySelectorAll("input").forEach((input) => { input.value = ""; });
    body.appendChild(row);
    renumber();
    row.querySelector("input").focus();
  });
  body.addEventListener("click", (event) => {
    const button = /** @type {Element} */ (event.target).closest(".remove-row");
    if (!button || body.rows.length <= 1) return;
    button.closest("tr").remove();
    renumber();
  });
})();
