// @ts-check
// My runs: choose runs for one zip or a comparison; the buttons say what the choice allows.
(function () {
  "use strict";
  const form = document.getElementById("run-choice");
  if (!form) return;
  const downloadMax = Number(form.dataset.downloadMax);
  const compareMax = Number(form.dataset.compareMax);
  const download = /** @type {HTMLButtonElement} */ (document.getElementById("download-chosen"));
  const compare = /** @type {HTMLButtonElement} */ (document.getElementById("compare-chosen"));
  const count = document.getElementById("chosen-count");
  const all = /** @type {HTMLInputElement | null} */ (document.getElementById("choose-all"));
  const boxes = () => Array.from(/** @type {NodeListOf<HTMLInputElement>} */ (form.querySelectorAll('input[name="ids"]')));

  function update() {
    const chosen = boxes().filter((box) => box.checked).length;
    download.disabled = chosen < 1 || chosen > downloadMax;
    compare.disabled = chosen < 2 || chosen > compareMax;
    if (chosen === 0) {
      count.textContent = "Choose runs below: up to " + downloadMax + " to download, 2 to " + compareMax + " to compare.";
    } else {
      let text = chosen + " run" + (chosen === 1 ? "" : "s") + " chosen.";
      if (chosen > compareMax) text += " Compare at most " + compareMax + ".";
      if (chosen > downloadMax) text += " Download at most " + downloadMax + ".";
      count.textContent = text;
    }
    if (all) {
      const total = boxes().length;
      all.checked = total > 0 && chosen === total;
      all.indeterminate = chosen > 0 && chosen < total;
    }
  }

  if (all) {
    all.addEventListener("change", () => {
      for (const box of boxes()) box.checked = all.checked;
      update();
    });
  }
  form.addEventListener("change", (event) => {
    if (event.target !== all) update();
  });
  update();
})();
