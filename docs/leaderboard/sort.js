"use strict";
// Click a column header to sort the table's rows by it; click again to reverse.
// Numeric columns sort by each cell's data-value (missing values last), text columns by text.
for (const table of document.querySelectorAll("table.sortable")) {
  const headers = Array.from(table.tHead.rows[0].cells);
  headers.forEach((th, col) => {
    const button = th.querySelector("button");
    if (!button) return;
    button.addEventListener("click", () => {
      const dir = th.getAttribute("aria-sort") === "ascending" ? "descending" : "ascending";
      headers.forEach((h) => h.removeAttribute("aria-sort"));
      th.setAttribute("aria-sort", dir);
      const numeric = th.dataset.type === "num";
      const key = (row) => {
        const cell = row.cells[col];
        if (numeric) return parseFloat(cell.dataset.value);
        return (cell.dataset.value ?? cell.textContent).trim().toLowerCase();
      };
      const sign = dir === "ascending" ? 1 : -1;
      const body = table.tBodies[0];
      const rows = Array.from(body.rows);
      rows.sort((a, b) => {
        const x = key(a), y = key(b);
        if (numeric) {
          if (Number.isNaN(x) || Number.isNaN(y)) return Number.isNaN(x) - Number.isNaN(y);
          return sign * (x - y);
        }
        return sign * x.localeCompare(y);
      });
      body.append(...rows);
    });
  });
}
