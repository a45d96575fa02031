// The frame list: one page of the filtered frames (the review queue by default) as table rows,
// its pager, selecting the rows, and the way into the review page.

import { api, query } from "../api.js";
import { score } from "../format.js";
import { badge, formatBytes, h, reviewBadge } from "../ui.js";
import { updateSelection } from "./actions.js";
import { filters, formValues, queueContext } from "./filters.js";
import { changed, filterForm, PAGE_SIZE, S, selected, WORK } from "./state.js";

const rows = document.getElementById("frame-rows");

function frameRow(frame) {
  const href = `/frames/${frame.id}${queueContext()}`;
  const box = h("input", {
    type: "checkbox", "aria-label": `select frame ${frame.id}`, checked: selected.has(frame.id),
    onchange: (event) => { event.target.checked ? selected.add(frame.id) : selected.delete(frame.id); updateSelection(); },
  });
  const uncertainty = score(frame.uncertainty);
  return h("tr", { "data-frame-id": String(frame.id), "data-testid": "frame-row" },
    h("td", {}, box),
    h("td", { class: "thumb" }, h("a", { href, tabindex: "-1" },
      h("img", { src: `/api/v1/frames/${frame.id}/image?variant=thumb`, alt: "", loading: "lazy", width: "96", height: String(Math.round(96 * frame.height / frame.width)) }))),
    h("td", {}, h("a", { href, class: "frame-link" }, `#${frame.id}`), " ",
      h("span", { class: "muted name" }, frame.original_name || (frame.frame_index !== null ? `frame ${frame.frame_index}` : ""))),
    h("td", { class: "muted" }, `${frame.width}×${frame.height}`, frame.bit_depth === 16 ? " · 16-bit" : "", h("br"), formatBytes(frame.size_bytes)),
    h("td", {}, badge(frame.status), frame.review ? [" ", reviewBadge(frame.review)] : null,
      frame.review === "returned" && frame.review_comment
        ? h("span", { class: "review-comment", "data-testid": "review-comment" }, `“${frame.review_comment}”`) : null),
    h("td", {}, frame.split),
    h("td", { "data-testid": "frame-assignee" }, frame.assignee ?? h("span", { class: "muted" }, "—")),
    h("td", { class: "num" }, uncertainty),
  );
}

export async function loadFrames() {
  const params = { ...filters(), limit: PAGE_SIZE, ...(S.nextAfter ? { after: S.nextAfter } : { offset: S.offset }) };
  S.nextAfter = null;
  try {
    S.lastPage = await api(`/frames${query(params)}`);
  } catch (error) {
    rows.replaceChildren(h("tr", {}, h("td", { colspan: "8", class: "error" }, error.message)));
    return;
  }
  const { lastPage, offset } = S;
  if (!lastPage.items.length && offset > 0) {
    S.offset = Math.max(0, offset - PAGE_SIZE);
    return loadFrames();
  }
  rows.replaceChildren(...(lastPage.items.length
    ? lastPage.items.map(frameRow)
    : [h("tr", {}, h("td", { colspan: "8", class: "empty", "data-testid": "frames-empty" },
        formValues().assignee === WORK
          ? "Nothing is waiting for you: nothing was sent back, and every frame handed to you is labelled."
        : filters().status === "unreviewed"
          ? "Nothing left to review here. Status “all” shows the frames already reviewed; drop frames above to add more."
          : "No frames match. Drop frames above, or import labels made elsewhere, to start."))]));
  const note = document.getElementById("order-note");
  note.textContent = lastPage.ordering ?? "";
  note.hidden = !lastPage.ordering || !lastPage.items.length;
  const last = Math.min(offset + PAGE_SIZE, lastPage.total);
  document.getElementById("page-info").textContent = lastPage.total ? `${offset + 1}–${last} of ${lastPage.total}` : "0 frames";
  document.getElementById("prev-page").disabled = offset === 0;
  document.getElementById("next-page").disabled = last >= lastPage.total;
  document.getElementById("select-all").checked = lastPage.items.length > 0 && lastPage.items.every((f) => selected.has(f.id));
  document.getElementById("review-queue").disabled = lastPage.total === 0;
}

filterForm.addEventListener("change", () => { S.offset = 0; changed("filters"); });
document.getElementById("prev-page").addEventListener("click", () => { S.offset = Math.max(0, S.offset - PAGE_SIZE); changed("filters"); });
document.getElementById("next-page").addEventListener("click", () => {
  S.offset += PAGE_SIZE;
  S.nextAfter = S.lastPage.next_after ?? null;
  changed("filters");
});
document.getElementById("select-all").addEventListener("change", (event) => {
  for (const frame of S.lastPage.items) event.target.checked ? selected.add(frame.id) : selected.delete(frame.id);
  updateSelection();
  loadFrames();
});
document.getElementById("review-queue").addEventListener("click", () => {
  const first = S.lastPage.items[0];
  if (first) location.href = `/frames/${first.id}${queueContext()}`;
});
