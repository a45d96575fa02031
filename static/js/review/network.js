// What the page sends and fetches: verdicts with revision checks and the conflict dialog,
// the queue's next frame, proposals, the teacher, propagation, the label's history.

import { ApiError, REVIEW_STAGE, api, jobFromButton, waitForJob } from "../api.js";
import { badge, formatDate, h, toast } from "../ui.js";
import { setHeatmapVisible } from "./display.js";
import { commit, isProposal, labelDirty, manualDirty } from "./history.js";
import { showConflict } from "./conflict.js";
import { adoptRetired, othersBody, othersFromLabel, retiredOf, selectLayer } from "./layers.js";
import { Mask, MaskOverlay } from "./mask.js";
import { $, CONTEXT, FRAME_ID } from "./page.js";
import { S, changed } from "./state.js";
import { toggleValidation } from "./validation.js";
import { refreshWork } from "../work.js";
import { saveOwn } from "./agreement.js";

export async function loadHistory() {
  try {
    const rows = await api(`/frames/${FRAME_ID}/label/history`);
    const list = $("history");
    list.replaceChildren(...rows.slice().reverse().slice(0, 8).map((r) =>
      h("li", {}, `rev ${r.revision} · `, badge(r.status), r.review ? ` · ${REVIEW_WORDS[r.review]}` : "",
        ` · ${r.user ?? "?"} · ${formatDate(r.created_at)}`,
        r.source?.kind === "imported" ? h("span", { class: "muted", "data-testid": "history-source" }, ` · imported from ${r.source.format ?? "a file"}${r.source.file ? ` (${r.source.file})` : ""}`) : "",
        r.review_comment ? h("br") : "",
        r.review_comment ? h("span", { class: "muted" }, `“${r.review_comment}”`) : "")));
    if (!rows.length) list.append(h("li", {}, "no label yet"));
  } catch { /* the history is a convenience */ }
}

// --- the first click: the embedding made while the page is open ----------------------------

const pause = (ms) => new Promise((resolve) => { setTimeout(resolve, ms); });

/** Ask the server to compute this frame's SAM2 embedding now, show how far it is, then ask
 *  for the next two frames of the queue (the server bounds how many it makes at once). */
export async function warmEmbedding() {
  const box = $("embed-state");
  const ask = (method, id = FRAME_ID) => api(`/frames/${id}/embedding`, { method });
  let answer;
  try { answer = await ask("POST"); } catch { return; } // clicks then compute it themselves
  const started = performance.now() - (answer.elapsed_ms ?? 0);
  while (answer.state !== "ready" && performance.now() - started < 120_000) {
    const seconds = (performance.now() - started) / 1000;
    const expected = answer.expected_ms ? ` of ~${(answer.expected_ms / 1000).toFixed(1)} s` : "";
    box.hidden = false;
    box.dataset.state = "computing";
    box.textContent = `preparing clicks… ${seconds.toFixed(1)} s${expected}`;
    await pause(400);
    try { answer = await ask(answer.state === "computing" ? "GET" : "POST"); } catch { box.hidden = true; return; }
  }
  if (answer.state !== "ready") { box.hidden = true; return; }
  box.hidden = false;
  box.dataset.state = "ready";
  box.textContent = "clicks ready";
  setTimeout(() => { box.hidden = true; }, 3000);
  try {
    const { ids } = await queueIds();
    const here = ids.indexOf(FRAME_ID);
    for (const id of ids.slice(here + 1, here + 3)) ask("POST", id).catch(() => {});
  } catch { /* the next frames are a convenience */ }
}

// --- the review stage ---------------------------------------------------------------------

const REVIEW_WORDS = { awaiting: "awaiting review", approved: "approved", returned: "sent back" };

/** The label's review state and its reviewer's decision, when the stage is on. */
export function reviewOf(label) {
  return label?.review ? { state: label.review, comment: label.review_comment, by: label.updated_by } : null;
}

async function decide(decision, comment) {
  try {
    const label = await api(`/frames/${FRAME_ID}/label/review`, { method: "POST", json: { decision, comment, base_revision: S.revision } });
    S.revision = label.revision;
    S.review = reviewOf(label);
    $("send-back-form").hidden = true;
    changed("review", "frame");
    loadHistory();
    toast(decision === "approve" ? "Approved: it trains from now on." : "Sent back to its annotator.", "ok");
    refreshWork();
  } catch (error) {
    toast(error.message, "error");
  }
}

export function bindReview() {
  $("approve").addEventListener("click", () => decide("approve"));
  $("approve-corrected").addEventListener("click", () => saveLabel("correct"));
  $("send-back").addEventListener("click", () => { $("send-back-form").hidden = false; $("send-back-form").elements.comment.focus(); });
  $("send-back-cancel").addEventListener("click", () => { $("send-back-form").hidden = true; });
  $("send-back-form").addEventListener("submit", (event) => {
    event.preventDefault();
    decide("return", event.target.elements.comment.value.trim());
  });
}

// --- verdicts -------------------------------------------------------------------------------

/** One PUT's body: the verdict on the pool, with the other classes' objects and the frame's
 *  tags and attributes where they changed, or all of them (`all`: mine kept whole over theirs);
 *  one revision for all of them. */
export async function verdictBody(kind, baseRevision, { all = false } = {}) {
  const from = { ...(S.proposal ? { proposal_id: S.proposal.id } : {}), ...(await othersBody({ all })) };
  if (kind === "reject") return { status: "rejected", base_revision: baseRevision, ...from };
  if (kind === "accept" && isProposal()) return { status: "accepted", base_revision: baseRevision, ...from };
  const body = { status: "corrected", base_revision: baseRevision, mask_png: await S.edit.mask.toPng(), ...from };
  const stale = S.edit.maskEdited && !S.edit.kpEdited;
  if (!stale && S.edit.keypoints.length) body.keypoints = S.edit.keypoints;
  return body;
}

export async function saveLabel(kind, baseRevision = S.revision, { all = false } = {}) {
  if (S.validation) toggleValidation();
  await Promise.allSettled([...S.inflight]);
  if (S.overlapMine) { // given to several: her own label, kept apart (agreement.js)
    if (await saveOwn() && $("advance").checked) await goNext({ afterSave: true });
    return;
  }
  // Accept (with no proposal to take) or save of a stored label left as it is: nothing to
  // write (it was saved again as a new "corrected" revision, in the saver's name). Not with
  // the review stage's decision pending: an unchanged label sent back may be sent again.
  const settled = !S.review || S.review.state === "approved";
  const unchanged = S.revision > 0 && S.labelStatus !== "rejected" && !labelDirty() && settled;
  if (unchanged && (kind === "correct" || (kind === "accept" && !isProposal()))) {
    toast(`Nothing changed: the label stays ${S.labelStatus} (revision ${S.revision}).`, "info");
    if ($("advance").checked) await goNext({ afterSave: true });
    return;
  }
  const body = await verdictBody(kind, baseRevision, { all });
  let label;
  try {
    label = await api(`/frames/${FRAME_ID}/label`, { method: "PUT", json: body });
  } catch (error) {
    if (error instanceof ApiError && error.status === 409) {
      return showConflict(kind, error, { overwrite: (revision) => saveLabel(kind, revision, { all: true }), take: takeLabel });
    }
    toast(error.message, "error");
    return;
  }
  S.revision = label.revision;
  S.labelStatus = label.status;
  S.review = reviewOf(label);
  S.loadedLabel = label.status === "rejected" ? null : { mask: S.edit.mask, revision: label.revision };
  S.frame.status = label.status;
  const rejected = label.status === "rejected"; // "no pool here": nothing stays drawn over it
  const keypoints = rejected ? [] : label.keypoints ?? S.edit.keypoints;
  const mask = rejected ? new Mask(S.frame.width, S.frame.height) : S.edit.mask;
  S.edit = { ...S.edit, mask, keypoints, outline: rejected ? null : S.edit.outline, maskEdited: false, kpEdited: false, session: null };
  S.labelClean = S.edit;
  adoptRetired(label); // and nothing named for removal any more
  changed("edit", "review", "frame", "propagate");
  loadHistory();
  const where = label.review === "awaiting" ? " — submitted for review" : label.review === "approved" && REVIEW_STAGE ? " — approved" : "";
  toast(`Saved as ${label.status} (revision ${label.revision})${where}.`, "ok");
  refreshWork();
  if ($("advance").checked) await goNext({ afterSave: true });
}

/** Their label taken in place of mine after a conflict: every class of it, one undo step
 *  (Undo brings mine back, unsaved). */
function takeLabel(label, mask) {
  const { width, height } = S.frame;
  S.revision = label.revision;
  S.labelStatus = label.status;
  S.review = reviewOf(label);
  S.loadedLabel = mask ? { mask, revision: label.revision } : null;
  S.frame.status = label.status;
  const keypoints = mask ? (label.keypoints ?? []).map((p) => [...p]) : [];
  const others = othersFromLabel(label, width, height);
  S.retired = retiredOf(label, others.objects); // theirs is the label now edited
  commit({ ...S.edit, mask: mask ?? new Mask(width, height), keypoints, ...others, removed: [], outline: null, maskEdited: false, kpEdited: false, session: null });
  S.labelClean = S.edit;
  selectLayer(S.layer);
  changed("edit", "review", "frame", "propagate");
  loadHistory();
  toast(`Took ${label.updated_by ?? "their"}'s label (revision ${label.revision}); Undo brings yours back.`, "info");
}

// --- the queue ------------------------------------------------------------------------------

export const SKIPPED_KEY = "weldpool.skipped";
export const skipped = () => new Set(JSON.parse(sessionStorage.getItem(SKIPPED_KEY) ?? "[]"));

export async function queueIds() {
  const params = new URLSearchParams(CONTEXT);
  params.set("limit", "500");
  params.delete("offset");
  const page = await api(`/frames?${params}`);
  return { ids: page.items.map((f) => f.id), total: page.total, ordering: page.ordering };
}

export async function goNext({ afterSave = false } = {}) {
  if (!afterSave && (labelDirty() || manualDirty())
      && !window.confirm("This frame has unsaved changes. Leave it without saving?")) return;
  let ids;
  try {
    ({ ids } = await queueIds());
  } catch (error) {
    toast(error.message, "error");
    return;
  }
  if (!afterSave) sessionStorage.setItem(SKIPPED_KEY, JSON.stringify([...skipped(), FRAME_ID].slice(-500)));
  const here = ids.indexOf(FRAME_ID);
  const seen = skipped();
  const next = here >= 0
    ? ids[here + 1]
    : ids.find((id) => id !== FRAME_ID && !seen.has(id)) ?? ids.find((id) => id !== FRAME_ID);
  if (next === undefined) {
    toast("That was the last frame of this queue.", "info");
    $("queue-position").textContent = "End of the queue — back to the frame list to pick another.";
    return;
  }
  S.leaving = true;
  location.href = `/frames/${next}?${CONTEXT}`;
}

export async function showQueuePosition() {
  try {
    const { ids, total, ordering } = await queueIds();
    const here = ids.indexOf(FRAME_ID);
    $("queue-position").title = ordering ?? "";
    const order = CONTEXT.get("order") === "uncertainty" ? "most uncertain first" : `order ${CONTEXT.get("order")}`;
    $("queue-position").textContent = here >= 0 ? `${here + 1} of ${total} in this queue (${order})` : `not in this queue (${order})`;
    const next = here >= 0 ? ids[here + 1] : ids[0];
    if (next !== undefined && next !== FRAME_ID) {
      document.head.append(h("link", { rel: "prefetch", as: "image", href: `/api/v1/frames/${next}/image?variant=display` }));
    }
  } catch { /* the position is a convenience */ }
}

/** Show another proposal of the frame: it replaces the working mask (undoable once edited). */
export async function switchProposal(id) {
  if (S.proposal && S.proposal.id === id) return;
  let body;
  try {
    body = await api(`/frames/${FRAME_ID}/proposal?proposal_id=${id}`);
  } catch (error) { toast(error.message, "error"); return; }
  const mask = await Mask.fromPng(body.mask_png, S.frame.width, S.frame.height);
  S.proposal = { ...body, mask };
  S.stage.heatmap = null;
  if (S.stage.showHeatmap) setHeatmapVisible(true);
  const next = { ...S.edit, mask, keypoints: (body.keypoints ?? []).map((p) => [...p]), maskEdited: false, kpEdited: false, session: null };
  if (S.revision === 0 && !labelDirty()) { S.edit = next; S.labelClean = next; changed(); }
  else commit(next);
  changed("proposals", "frame");
  S.stage.requestRender();
}

// --- loading --------------------------------------------------------------------------------

export async function optional(path) {
  try { return await api(path); } catch (error) {
    if (error instanceof ApiError && error.status === 404) return null;
    throw error;
  }
}

export function loadImage(url) {
  const image = new Image();
  image.src = url;
  return image.decode().then(() => image);
}

export async function propagateFromHere() {
  const threshold = Math.min(1, Math.max(0, Number($("propagate-threshold").value) || 0));
  const direction = $("propagate-direction").value;
  const body = { from_frame_ids: [FRAME_ID], direction, threshold };
  const until = $("propagate-until").value.trim();
  if (direction !== "both" && until !== "") body.until_frame_index = Math.max(0, Math.round(Number(until)));
  try {
    const job = await jobFromButton($("propagate"), () => api(`/sequences/${S.frame.sequence_id}/propagate`, { method: "POST", json: body }), "Propagating");
    if (job.status !== "succeeded") throw new Error(`The propagation job ${job.status}: ${job.error ?? job.message ?? ""}`);
    $("propagate-note").replaceChildren(`${job.message}. `, h("a", { href: `/sequences/${S.frame.sequence_id}`, "data-testid": "timeline-link" }, "Open the run's timeline"), ".");
    toast(`Propagation done: ${job.message}.`, "ok");
  } catch (error) {
    toast(error.message, "error");
  } finally {
    changed("propagate");
  }
}

export async function runTeacher(force) {
  const button = $(force ? "rerun-teacher" : "run-teacher");
  const text = button.textContent;
  button.disabled = true;
  try {
    const { job_id: jobId } = await api("/teacher/runs", { method: "POST", json: { frame_ids: [FRAME_ID], force } });
    const job = await waitForJob(jobId, (j) => { button.textContent = `Teacher: ${Math.round(j.progress * 100)} %`; });
    if (job.status !== "succeeded") throw new Error(`The teacher job ${job.status}: ${job.error ?? ""}`);
    if (labelDirty() || manualDirty()) toast("The proposal is ready; save or undo your changes, then reload.", "info");
    else { S.leaving = true; location.reload(); }
  } catch (error) {
    toast(error.message, "error");
    button.disabled = false;
    button.textContent = text;
  }
}
