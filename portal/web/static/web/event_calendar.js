// @ts-check
// What the calendar and the timeline do alike to Event Calendar's drawing.
window.AmazingEventCalendar = (function () {
  "use strict";
  // Event Calendar marks its grids up as tables without the rows and cells a table needs,
  // which misleads screen readers; the drawing is shown as plain content instead (its
  // bookings are buttons and links, its times are named in text, and the Book page is the
  // form-based way to book).
  const GRID_ROLES = new Set(["grid", "treegrid", "table", "rowgroup", "row", "rowheader", "columnheader", "gridcell", "cell"]);
  const GRID_ATTRS = ["aria-colindex", "aria-rowindex", "aria-colcount", "aria-rowcount", "aria-colspan", "aria-rowspan", "aria-selected", "aria-readonly"];

  function plainRoles(el) {
    for (const node of [el, ...el.querySelectorAll("[role]")]) {
      if (GRID_ROLES.has(node.getAttribute("role"))) node.removeAttribute("role");
    }
    for (const name of GRID_ATTRS) {
      for (const node of el.querySelectorAll(`[${name}]`)) node.removeAttribute(name);
    }
  }

  // The calendar in `el` kept plain, however often it redraws.
  function keepPlain(el) {
    plainRoles(el);
    new MutationObserver(() => plainRoles(el)).observe(el, { childList: true, subtree: true });
  }

  return { keepPlain };
})();
