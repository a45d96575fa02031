// The frames page's state: the filter form, the page of the list shown, the frames selected,
// and the one notification of their changes. A module that changes what the page shows calls
// `changed` with what changed; the page's entry (frames.js) subscribes the views once, so no
// module imports the functions that load or draw another part of the page.

export const PAGE_SIZE = 50;
export const FILTERS = ["sequence_id", "status", "split", "review", "assignee", "order", "class", "tag", "attr"];
/** The assignee filter's value for "my work". */
export const WORK = "work";

export const filterForm = document.getElementById("filters");
export const selected = new Set();

export const S = {
  offset: Number(new URLSearchParams(location.search).get("offset") ?? 0) || 0,
  lastPage: { items: [], total: 0 },
  // "Next" follows the server's cursor (a deep page then reads only its own rows); a reload or
  // "previous" uses the offset in the URL.
  nextAfter: null,
};

// --- the one state-change notification ------------------------------------------------------

/** What a change may touch: "sequences" (the weld runs), "frames" (the rows of the list),
 *  "filters" (the filters or the page: the URL, the upload target and the list follow them). */
export const PARTS = new Set(["sequences", "frames", "filters"]);
const views = [];

/** Call `view(parts)` after every change, with the set of parts changed. */
export function subscribe(view) {
  views.push(view);
}

/** Say that `parts` changed; resolves once every view has followed. */
export async function changed(...parts) {
  const what = new Set(parts);
  for (const part of what) if (!PARTS.has(part)) throw new Error(`No part of the frames page is called ${part}.`);
  for (const view of views) await view(what);
}
