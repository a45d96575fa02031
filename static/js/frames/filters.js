// The frames list's filters and the URL that keeps them: what the form holds, what the API
// takes, and where a person lands when the URL names no filter.

import { api, isReviewer, query } from "../api.js";
import { count } from "../format.js";
import { toast } from "../ui.js";
import { FILTERS, S, WORK, filterForm } from "./state.js";

/** The filters as the form holds them (and the URL keeps them). */
export function formValues() {
  const values = Object.fromEntries(new FormData(filterForm));
  values.order ||= "uncertainty";
  return values;
}

/** The filters as the API takes them: "my work" is the assignee filter `me` with no status
 * or review filter (the server's list: sent back to me first, then still to review). */
export function filters() {
  const values = formValues();
  if (values.assignee === WORK) {
    values.assignee = "me";
    delete values.status;
    delete values.review;
  }
  return values;
}

/** Status and review do not apply to "my work": the list is the person's work itself. */
export function syncWorkFilter() {
  const work = filterForm.elements.assignee.value === WORK;
  for (const name of ["status", "review"]) {
    const field = filterForm.elements[name];
    if (field) { field.disabled = work; field.title = work ? "“Assigned: my work” lists what was sent back to you, then what is still to review" : ""; }
  }
}

/** The list's filters as the review page's queue context. */
export function queueContext() {
  return query(filters());
}

export function restoreFilters() {
  const params = new URLSearchParams(location.search);
  for (const name of FILTERS) {
    const field = filterForm.elements[name];
    if (params.has(name)) field.value = params.get(name);
  }
  filterForm.elements.unstable.checked = params.get("unstable") === "true"; // a checkbox: no value to set
  if (!filterForm.elements.order.value) filterForm.elements.order.value = "uncertainty";
}

export function syncUrl() {
  history.replaceState(null, "", `/${query({ ...formValues(), offset: S.offset || "" })}`);
}

/** Where a person lands (unless the URL names filters): an annotator on her work (what was
 * sent back to her, then what is handed to her); a reviewer on what awaits his approval, else
 * on the frames handed to him. */
export async function landing() {
  if (FILTERS.some((name) => new URLSearchParams(location.search).has(name))) return;
  const work = await api("/users/me/work").catch(() => null);
  if (!work) return;
  if (isReviewer() && work.awaiting_review && filterForm.elements.review) {
    filterForm.elements.review.value = "awaiting";
    filterForm.elements.status.value = "all";
    filterForm.elements.order.value = "id";
    toast(`${count(work.awaiting_review, "label")} await${work.awaiting_review > 1 ? "" : "s"} your approval: shown first. “Review: any” shows every frame.`, "info", 6000);
  } else if (work.sent_back || work.assigned) {
    filterForm.elements.assignee.value = WORK;
    const parts = [work.sent_back ? `${count(work.sent_back, "label")} sent back to you` : "", work.assigned ? `${count(work.assigned, "frame")} handed to you` : ""];
    toast(`Your work first: ${parts.filter(Boolean).join(", then ")}. “Assigned: to anyone” shows all.`, "info", 6000);
  }
}
