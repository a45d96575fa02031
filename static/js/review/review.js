// The review page: one frame with its proposal or label, click corrections through the segment
// endpoint, brush and eraser, keypoint editing, undo / redo, the verdict with revision checks,
// the queue's next frame, and the validation mode for keypoints placed by hand.
//
// Modules by concern, from the bottom: state.js (the one state object and its change
// notification), page.js (constants), history.js (undo, redo, what is unsaved), display.js
// (preferences and overlays), keypoints.js (their numbers), tools.js (editing tools and pointer
// gestures), validation.js (keypoints placed by hand), agreement.js and network.js (verdicts,
// queue, proposals, teacher, propagation), panel.js (what the panel and canvas show); this
// module subscribes the panel to the state's changes, binds the controls and starts the page.

import { SAM2_PROBLEM, TEACHER_PROBLEM, api, isReviewer } from "../api.js";
import { formatDate, toast } from "../ui.js";
import { loadAgreement } from "./agreement.js";
import { bindDisplay, prefs, setHeatmapVisible, setMaskVisible } from "./display.js";
import { commit, labelDirty, manualDirty, redo, undo } from "./history.js";
import { deleteKeypoint } from "./keypoints.js";
import { renderClasses } from "./classes.js";
import { kindOf, objectsFromLabel, retiredOf, setConfig } from "./layers.js";
import { classForKey, pickClass } from "./picker.js";
import { removePoint } from "./points.js";
import { Mask, MaskOverlay } from "./mask.js";
import { bindReview, warmEmbedding, goNext, loadHistory, loadImage, optional, propagateFromHere, reviewOf, runTeacher, saveLabel, showQueuePosition, switchProposal } from "./network.js";
import { $, FRAME_ID } from "./page.js";
import { render, timelineNote } from "./panel.js";
import { ScaleRuler } from "./scale.js";
import { Stage } from "./stage.js";
import { S, changed, subscribe } from "./state.js";
import { closePolygon, enableTools, endSession, local, onPointerDown, onPointerMove, onPointerUp, removeVertex, setBrushSize, setOutlineTolerance, setTool, toolUsable } from "./tools.js";
import { saveValidation, toggleValidation } from "./validation.js";

// --- proposals ------------------------------------------------------------------------------

export function cycleProposal() {
  if (S.proposals.length < 2) return;
  const index = S.proposals.findIndex((item) => S.proposal && item.id === S.proposal.id);
  switchProposal(S.proposals[(index + 1) % S.proposals.length].id);
}

export function deleteSelected() {
  if (kindOf() === "points" && !S.validation) { if (S.selectedPoint) removePoint(S.selectedPoint); return; }
  if (S.tool === "polygon" && S.stage.selectedVertex && S.edit.outline?.mask) removeVertex(S.stage.selectedVertex);
  else if (S.stage.selected >= 0) deleteKeypoint(S.stage.selected);
}

// --- keyboard -------------------------------------------------------------------------------

export const TOOL_KEYS = { 1: "positive", 2: "negative", 3: "box", 4: "brush", 5: "eraser", 6: "keypoint", 7: "polygon" };

export function onKey(event) {
  const target = event.target;
  if (target instanceof HTMLElement && target.matches("input[type=text], input[type=number], textarea, select")) return;
  if ($("conflict").open) return;
  const key = event.key.toLowerCase();
  const ctrl = event.ctrlKey || event.metaKey;
  if (ctrl && key === "z") { event.preventDefault(); event.shiftKey ? redo() : undo(); return; }
  if (ctrl && key === "y") { event.preventDefault(); redo(); return; }
  if (ctrl && key === "s") { event.preventDefault(); saveLabel("correct"); return; }
  if (ctrl || event.altKey) return;
  if (key === " ") {
    if (target instanceof HTMLInputElement || target instanceof HTMLButtonElement) return;
    S.spaceHeld = true;
    S.stage.canvas.classList.add("panning");
    event.preventDefault();
    return;
  }
  if (TOOL_KEYS[key]) { setTool(TOOL_KEYS[key]); return; }
  if (key === "enter" && S.stage.newPolygon) { event.preventDefault(); closePolygon(); return; }
  const actions = {
    "[": () => setBrushSize(Number($("brush-size").value) - 4),
    "]": () => setBrushSize(Number($("brush-size").value) + 4),
    a: () => !$("accept").disabled && saveLabel("accept"),
    r: () => !$("reject").disabled && saveLabel("reject"),
    s: () => saveLabel("correct"),
    n: () => goNext(),
    m: () => setMaskVisible(!S.stage.showMask),
    h: () => ($("show-heatmap").disabled ? toast("No proposal here: it has no heatmap to show.", "info") : setHeatmapVisible(!S.stage.showHeatmap)),
    f: () => S.stage.fit(),
    v: () => toggleValidation(),
    l: () => !$("measure-scale").disabled && S.ruler.toggle(),
    p: () => cycleProposal(),
    escape: () => { S.stage.draft = null; S.stage.newPolygon = null; S.gesture = null; if (S.ruler.active) S.ruler.toggle(); else endSession(); },
    delete: () => deleteSelected(),
    backspace: () => deleteSelected(),
  };
  if (actions[key]) { event.preventDefault(); actions[key](); return; }
  const picked = classForKey(key); // a class's hotkey: the page's own keys come first
  if (picked) { event.preventDefault(); pickClass(picked.name); }
}

export function fail(message) {
  $("stage-message").textContent = message;
  $("stage-message").classList.add("error");
  for (const button of document.querySelectorAll(".verdict button, .toolbar button")) button.disabled = true;
}

export function bindControls() {
  const canvas = S.stage.canvas;
  canvas.addEventListener("pointerdown", onPointerDown);
  canvas.addEventListener("pointermove", onPointerMove);
  canvas.addEventListener("pointerup", onPointerUp);
  canvas.addEventListener("pointercancel", onPointerUp);
  canvas.addEventListener("pointerleave", () => { if (S.stage.cursor) { S.stage.cursor = null; S.stage.requestRender(); } });
  canvas.addEventListener("contextmenu", (event) => event.preventDefault());
  canvas.addEventListener("wheel", (event) => {
    event.preventDefault();
    const [sx, sy] = local(event);
    S.stage.zoomAt(Math.exp(-event.deltaY * 0.0015), sx, sy);
  }, { passive: false });
  S.stage.onViewChange = () => {
    $("zoom-level").textContent = `${Math.round(S.stage.scale * 100)} %`;
    S.stage.canvas.dataset.view = JSON.stringify({ scale: S.stage.scale, tx: S.stage.tx, ty: S.stage.ty });
  };
  S.stage.onViewChange();
  // Tool buttons hand the keyboard back to the canvas (Space pans there, it must not click).
  for (const button of document.querySelectorAll("#tools .tool")) {
    button.addEventListener("click", () => { setTool(button.dataset.tool); S.stage.canvas.focus(); });
  }
  $("brush-size").addEventListener("input", (event) => setBrushSize(Number(event.target.value)));
  $("outline-tolerance").addEventListener("change", setOutlineTolerance);
  $("undo").addEventListener("click", undo);
  $("redo").addEventListener("click", redo);
  $("fit").addEventListener("click", () => S.stage.fit());
  $("show-mask").addEventListener("change", (event) => setMaskVisible(event.target.checked));
  $("show-heatmap").addEventListener("change", (event) => setHeatmapVisible(event.target.checked));
  $("accept").addEventListener("click", () => saveLabel("accept"));
  $("reject").addEventListener("click", () => saveLabel("reject"));
  $("save").addEventListener("click", () => saveLabel("correct"));
  $("next").addEventListener("click", () => goNext());
  $("validation-toggle").addEventListener("click", toggleValidation);
  $("save-validation").addEventListener("click", saveValidation);
  $("clear-validation").addEventListener("click", () => S.edit.manual.length && commit({ ...S.edit, manual: [] }));
  $("run-teacher").addEventListener("click", () => runTeacher(false));
  $("propagate").addEventListener("click", propagateFromHere);
  $("propagate-direction").addEventListener("change", () => {
    $("propagate-until").disabled = $("propagate-direction").value === "both";
  });
  $("rerun-teacher").addEventListener("click", () => runTeacher(true));
  for (const id of ["run-teacher", "rerun-teacher"]) { // they cannot work: say why instead
    if (TEACHER_PROBLEM) Object.assign($(id), { disabled: true, title: TEACHER_PROBLEM });
  }
  $("advance").checked = localStorage.getItem("weldpool.advance") !== "0";
  $("advance").addEventListener("change", (event) => localStorage.setItem("weldpool.advance", event.target.checked ? "1" : "0"));
  document.addEventListener("keydown", onKey);
  document.addEventListener("keyup", (event) => {
    if (event.key === " ") { S.spaceHeld = false; S.stage.canvas.classList.remove("panning"); }
  });
  window.addEventListener("beforeunload", (event) => {
    if (!S.leaving && (labelDirty() || manualDirty())) { event.preventDefault(); event.returnValue = ""; }
  });
  if (!isReviewer()) {
    for (const id of ["accept", "reject"]) $(id).title = "Accepting and rejecting need the reviewer role; save as corrected instead.";
  }
}

// --- start ---------------------------------------------------------------------------------

export async function start() {
  const imageUrl = `/api/v1/frames/${FRAME_ID}/image?variant=display`;
  const image = loadImage(imageUrl);
  image.catch(() => {});
  let detail, proposalBody, label, manual, listing, config;
  try {
    // The frame says what it has, so nothing absent is asked for (no 404s in the log).
    detail = await api(`/frames/${FRAME_ID}`);
    [proposalBody, label, manual, listing, config] = await Promise.all([
      detail.proposal ? optional(`/frames/${FRAME_ID}/proposal`) : null,
      detail.label ? optional(`/frames/${FRAME_ID}/label`) : null,
      detail.has_validation_keypoints ? optional(`/frames/${FRAME_ID}/validation-keypoints`) : null,
      detail.proposal ? optional(`/frames/${FRAME_ID}/proposals`) : null,
      api("/label-config").catch(() => null), // without it: the pool alone
    ]);
  } catch (error) {
    fail(error.message);
    return;
  }
  S.frame = detail;
  setConfig(config);
  const { width, height } = S.frame;
  const [picture, proposalMask, labelMask] = await Promise.all([
    image.catch(() => null),
    proposalBody ? Mask.fromPng(proposalBody.mask_png, width, height) : null,
    label?.mask_png ? Mask.fromPng(label.mask_png, width, height) : null,
  ]);
  if (!picture) { fail(`The image of frame ${FRAME_ID} could not be loaded.`); return; }
  if (proposalBody) S.proposal = { ...proposalBody, mask: proposalMask };
  S.proposals = listing?.items ?? [];
  S.policyReason = listing?.policy?.reason ?? "";
  S.revision = label?.revision ?? 0;
  S.labelStatus = label?.status ?? null;
  S.review = reviewOf(label);
  S.loadedLabel = labelMask ? { mask: labelMask, revision: S.revision } : null;

  S.stage = new Stage($("frame-canvas"), width, height);
  S.stage.image = picture;
  S.overlay = new MaskOverlay(width, height);
  S.stage.overlay = S.overlay;
  const rejected = label?.status === "rejected"; // "no pool here": nothing is drawn over it
  const keypoints = (labelMask ? label.keypoints : rejected ? [] : S.proposal?.keypoints) ?? [];
  const objects = objectsFromLabel(label, width, height);
  S.retired = retiredOf(label, objects);
  S.edit = {
    mask: labelMask ?? (rejected ? null : S.proposal?.mask) ?? new Mask(width, height),
    keypoints: keypoints.map((p) => [...p]),
    manual: (manual?.keypoints ?? []).map((p) => [...p]),
    session: null,
    outline: null,
    maskEdited: false,
    kpEdited: false,
    objects, // the other classes' (layers.js)
    removed: [], // the retired ones' × taken here (layers.js)
    tags: label?.tags ?? [],
    attributes: label?.attributes ?? {},
  };
  S.labelClean = S.edit;
  S.manualClean = S.edit.manual;
  S.manualRevision = manual?.revision ?? 0;
  if (manual) $("validation-state").textContent = `${manual.keypoints.length} keypoints placed by hand (${formatDate(manual.updated_at)}).`;
  $("no-proposal").hidden = S.proposal !== null || S.revision > 0; // reviewed: nothing to propose
  $("teacher-error").hidden = !S.frame.teacher_error;
  $("teacher-error").textContent = S.frame.teacher_error ? `The teacher's last run failed here: ${S.frame.teacher_error}` : "";
  $("show-heatmap").disabled = S.proposal === null;
  $("stage-message").hidden = true;
  S.ruler = new ScaleRuler(S.stage, S.frame);
  S.ruler.load();
  bindControls();
  bindReview();
  changed("review", "proposals", "propagate");
  timelineNote();
  bindDisplay();
  const saved = prefs();
  if (saved.brush) setBrushSize(saved.brush);
  enableTools();
  const start = Object.values(TOOL_KEYS).includes(saved.tool) ? saved.tool : "positive";
  setTool(toolUsable(start) ? start : "brush");
  changed("frame", "edit");
  S.stage.render();
  S.stage.canvas.dataset.ready = "1";
  document.body.dataset.ready = "1";
  performance.mark("weldpool:interactive");
  showQueuePosition();
  loadHistory();
  loadAgreement();
  if (!SAM2_PROBLEM) warmEmbedding();
}

subscribe(render);
subscribe(renderClasses);
start();
