// The review page's side panel and canvas drawn from the state: the frame and its status, the
// proposals, the review stage and verdict buttons, the keypoint list, propagation. The page's
// entry (review.js) subscribes `render` to the state's changes once; no module imports this one
// but the entry, so whatever changes the state calls `changed` (state.js) instead.

import { REVIEW_STAGE, ROLE, SAM2_PROBLEM, isReviewer } from "../api.js";
import { score } from "../format.js";
import { badge, formatDate, h, reviewBadge } from "../ui.js";
import { exposeState, isProposal, labelDirty, manualDirty } from "./history.js";
import { deleteKeypoint, numbersOf } from "./keypoints.js";
import { switchProposal } from "./network.js";
import { $, K } from "./page.js";
import { S } from "./state.js";
import { showOutline } from "./tools.js";

/** Redraw the parts of the page that show the `parts` of the state changed (state.js). */
export function render(parts) {
  if (parts.has("edit")) renderEdit();
  if (parts.has("review")) renderReview();
  if (parts.has("frame")) renderFrameInfo();
  if (parts.has("proposals")) renderProposals();
  if (parts.has("propagate")) renderPropagate();
}

// --- the editing state ----------------------------------------------------------------------

/** The editing state on the canvas and in the side panel. */
function renderEdit() {
  if (S.overlay.mask !== S.edit.mask) S.overlay.paint(S.edit.mask);
  showOutline();
  exposeState();
  S.stage.keypoints = S.validation ? S.edit.manual : S.edit.keypoints;
  S.stage.keypointNumbers = numbersOf(S.stage.keypoints);
  S.stage.keypointStyle = S.validation ? "manual" : "keypoint";
  S.stage.dimKeypoints = !S.validation && S.edit.maskEdited && !S.edit.kpEdited;
  if (S.stage.selected >= S.stage.keypoints.length) S.stage.selected = -1;
  S.stage.points = S.edit.session?.points ?? [];
  S.stage.box = S.edit.session?.box ?? null;
  S.stage.requestRender();
  $("undo").disabled = !S.past.length;
  $("redo").disabled = !S.future.length;
  $("dirty").hidden = !labelDirty() && !manualDirty();
  renderKeypointList();
  renderManualCount();
  renderVerdictNote();
}

function renderKeypointList() {
  const list = $("keypoint-list");
  const points = S.validation ? S.edit.manual : S.edit.keypoints;
  const numbers = numbersOf(points);
  list.replaceChildren(...points.map(([x, y], i) => h("li", { class: i === S.stage.selected ? "selected" : "", "data-number": String(numbers[i]) },
    h("span", { class: "kp-number" }, `${numbers[i]}.`), " ",
    h("span", {}, `${x.toFixed(1)}, ${y.toFixed(1)}`),
    h("button", { type: "button", class: "quiet tiny-btn", title: "Remove this keypoint", onclick: () => deleteKeypoint(i) }, "×"))));
  if (!points.length) list.append(h("li", { class: "muted plain" }, S.validation ? "none placed yet" : "none"));
  if (S.stage.dimKeypoints) list.append(h("li", { class: "muted plain" }, "The mask changed: the keypoints are recomputed from it on save, unless you move one."));
}

function renderManualCount() {
  $("manual-count").textContent = `${S.edit.manual.length} of ${K} placed`;
  $("save-validation").disabled = S.edit.manual.length !== K || !manualDirty();
}

// --- verdicts and the review stage ---------------------------------------------------------

/** One set of verdicts per role and state. With the review stage on an annotator submits
 * (Save), and a reviewer facing an awaiting label approves it, sends it back, or corrects it
 * and approves it in one step; on labels of his own he accepts, rejects or saves as before
 * (approved as he saves them). */
function renderVerdictNote() {
  const note = $("verdict-note");
  const deciding = REVIEW_STAGE && isReviewer() && S.review?.state === "awaiting";
  const submitting = (REVIEW_STAGE || S.overlapMine) && !isReviewer();
  for (const id of ["accept", "reject"]) {
    $(id).hidden = deciding || submitting;
    $(id).disabled = !isReviewer() || deciding;
  }
  $("save").hidden = deciding;
  $("save").firstChild.textContent = S.overlapMine ? "Save my label " : submitting ? "Submit for review " : "Save as corrected ";
  $("save").title = submitting ? "Submit for review (S): a reviewer approves it or sends it back" : "Save as corrected (S)";
  $("approve-corrected").disabled = !labelDirty();
  $("approve-corrected").title = labelDirty()
    ? "Save the label as you corrected it, approved, in one step (S)"
    : "Correct the mask or keypoints first; Approve keeps the annotator's label as it is";
  if (S.overlapMine) {
    note.textContent = "Your own label of a frame given to several annotators: a reviewer approves one of them or merges them.";
  } else if (deciding) {
    note.textContent = "Approve keeps the annotator's label; Send back returns it with what to change; or correct it here and “Correct and approve” saves yours, approved.";
  } else if (submitting) {
    note.textContent = S.review?.state === "returned"
      ? "Change what the reviewer asked, then submit again."
      : "A reviewer approves your label (it trains from then on) or sends it back with a comment.";
  } else if (!isReviewer()) {
    note.textContent = `As ${ROLE} you save corrections; a reviewer accepts or rejects.`;
  } else {
    const own = REVIEW_STAGE ? "Your own labels count as approved. " : "";
    note.textContent = own + (!S.proposal || !S.edit ? "No proposal: Accept saves what you drew as corrected."
      : !isProposal() ? "The label shown differs from the proposal: Accept saves it as corrected."
        : "Accept keeps the proposal as it is.");
  }
}

function renderReview() {
  const box = $("review-stage");
  const review = S.review;
  box.hidden = !REVIEW_STAGE || !review;
  if (box.hidden) return;
  box.dataset.state = review.state;
  const text = {
    awaiting: "Awaiting a reviewer's approval: it trains once approved.",
    approved: `Approved${review.by ? ` by ${review.by}` : ""}: the student learns from it.`,
    returned: `Sent back${review.by ? ` by ${review.by}` : ""}: “${review.comment ?? ""}” — correct it and submit again.`,
  }[review.state];
  $("review-state").textContent = text;
  $("review-actions").hidden = !isReviewer() || review.state === "approved";
  $("send-back").hidden = review.state === "returned";
  $("approve-corrected").hidden = review.state !== "awaiting";
  renderVerdictNote();
}

// --- the frame -----------------------------------------------------------------------------

/** Why a frame ranks high in the queue, in words (see weldpool_core.active). */
const REASONS = {
  teacher_iou: "SAM2's own doubt about its mask",
  instability: "the mask changing when the prompts move slightly",
  disagreement: "the student disagreeing with the teacher",
  student_uncertainty: "the student's own doubt (unstable under small changes, or unlike what it learnt from)",
  propagation_doubt: "SAM2's doubt about the mask it carried here from a reviewed frame",
};

function renderFrameInfo() {
  $("frame-title").textContent = `Frame #${S.frame.id}`;
  const parts = [S.frame.original_name, `${S.frame.width}×${S.frame.height}`, `${S.frame.bit_depth}-bit`, `${S.frame.split} split`];
  if (S.frame.frame_index !== null) parts.push(`index ${S.frame.frame_index}`);
  if (S.frame.assignee) parts.push(`assigned to ${S.frame.assignee}`);
  $("frame-meta").textContent = parts.filter(Boolean).join(" · ");
  // With the review stage, the badge says where the label stands; its verdict follows.
  const stage = REVIEW_STAGE && S.review;
  const pieces = [stage ? reviewBadge(S.review.state) : badge(S.frame.status)];
  if (S.revision) pieces.push(h("span", { class: "muted" }, stage ? ` ${S.frame.status} · revision ${S.revision}` : ` revision ${S.revision}`));
  if (S.proposal) {
    const iou = S.proposal.scores?.sam2_iou;
    pieces.push(h("br"), h("span", { class: "muted", "data-testid": "proposal-source" }, `${sourceName(S.proposal)} proposal`, iou !== undefined && iou !== null ? ` · SAM2 IoU ${score(Number(iou))}` : ""));
    if (S.proposal.scores?.low_confidence) pieces.push(h("br"), h("span", { class: "warning" }, "SAM2 lost confidence here: correct this frame and propagate again from it."));
    if (S.frame.uncertainty !== null) {
      // A component this page has no words for yet reads as words, never as a raw key.
      const reason = REASONS[S.frame.uncertainty_reason] ?? S.frame.uncertainty_reason?.replaceAll("_", " ");
      pieces.push(h("br"), h("span", { class: "uncertainty", "data-testid": "uncertainty-reason" },
        `uncertainty ${score(S.frame.uncertainty)}`, reason ? ` — mostly ${reason}` : ""));
    }
    if (S.proposal.scores?.warning) pieces.push(h("br"), h("span", { class: "warning" }, S.proposal.scores.warning));
  }
  $("frame-state").replaceChildren(...pieces);
  $("frame-state").dataset.status = S.frame.status;
}

// --- proposals ------------------------------------------------------------------------------

/** "teacher", the student version's name, or where a propagated mask came from. */
function sourceName(item) {
  if (item.source === "teacher") return "teacher";
  if (item.source === "propagated") {
    const confidence = item.scores?.confidence;
    return `propagated from #${item.scores?.from_frame_id}` + (confidence !== undefined ? ` (confidence ${score(Number(confidence))})` : "");
  }
  return `${item.source} ${item.model_id}`;
}

/** One button per proposal (newest first): the shown one pressed, the policy's pick marked. */
function renderProposals() {
  const list = $("proposal-sources");
  list.replaceChildren(...S.proposals.map((item) => {
    const iou = item.scores?.sam2_iou;
    const detail = iou !== undefined && iou !== null ? ` · SAM2 IoU ${score(Number(iou))}` : "";
    return h("button", {
      type: "button",
      class: `source${S.proposal && item.id === S.proposal.id ? " shown" : ""}`,
      "aria-pressed": String(Boolean(S.proposal && item.id === S.proposal.id)),
      "data-testid": "proposal-option",
      "data-proposal-id": String(item.id),
      title: `${sourceName(item)}, ${formatDate(item.created_at)}`,
      onclick: () => switchProposal(item.id),
    }, sourceName(item), h("span", { class: "muted" }, detail), item.chosen ? h("span", { class: "chosen" }, " ★ chosen") : "");
  }));
  $("proposals-section").hidden = S.proposals.length === 0;
  $("policy-reason").textContent = S.proposals.length > 1 ? S.policyReason : "";
  $("rerun-teacher").hidden = S.proposals.length === 0;
}

// --- propagation through the weld run -------------------------------------------------------

function renderPropagate() {
  const button = $("propagate");
  const reviewed = S.labelStatus === "accepted" || S.labelStatus === "corrected";
  button.disabled = !S.frame.sequence_id || !reviewed || Boolean(SAM2_PROBLEM) || !isReviewer();
  button.title = SAM2_PROBLEM
    || (!isReviewer() ? "A reviewer propagates: it writes proposals over the whole run."
      : !S.frame.sequence_id ? "This frame belongs to no weld run."
      : reviewed ? "SAM2's video model carries this frame's reviewed mask to the run's other frames"
        : "Accept or correct this frame first: propagation starts from a reviewed mask.");
}

export function timelineNote() {
  $("propagate-note").replaceChildren(...(S.frame.sequence_id
    ? [h("a", { href: `/sequences/${S.frame.sequence_id}`, "data-testid": "timeline-link" }, "The run's timeline"), " — geometry and confidence per frame."]
    : []));
}
