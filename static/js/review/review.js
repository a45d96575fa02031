// The review page: one frame with its proposal or label, click corrections through the segment
// endpoint, brush and eraser, keypoint editing, undo / redo, the verdict with revision checks,
// the queue's next frame, and the validation mode for keypoints placed by hand.
//
// Every edit makes a new immutable `state` ({mask, keypoints, manual, session, outline,
// maskEdited, kpEdited}); undo and redo move between them, and "unsaved" means the shown mask or keypoints
// are not the ones last loaded or saved.

import { api, ApiError, isReviewer, jobFromButton, ROLE, SAM2_PROBLEM, TEACHER_PROBLEM, waitForJob } from "../api.js";
import { badge, formatDate, h, toast } from "../ui.js";
import { score } from "../format.js";
import { Mask, MaskOverlay } from "./mask.js";
import { ScaleRuler } from "./scale.js";
import { Stage } from "./stage.js";

const FRAME_ID = Number(document.getElementById("review").dataset.frameId);
const K = 4;
const HISTORY_LIMIT = 40; // each step may hold a full-frame mask (1 MB at 1280×800)
const OUTLINE_TOLERANCE = 1; // pixels: a vertex where the boundary turns, not on every pixel
const $ = (id) => document.getElementById(id);

/** The list's filters this frame was opened from: the queue that "next" walks. */
const CONTEXT = new URLSearchParams(location.search);
if (!CONTEXT.has("order")) CONTEXT.set("order", "uncertainty");
if (!CONTEXT.has("status")) CONTEXT.set("status", "unreviewed"); // the queue: what is still to review

let frame = null;
let proposal = null; // the proposal shown: {id, mask, keypoints, scores, source, source_key, model_id, chosen}
let proposals = []; // every proposal of the frame, newest first (GET /proposals items)
let policyReason = "";
let revision = 0;
let labelStatus = null;
let stage = null;
let ruler = null; // measuring the run's scale: two ends of a known length
let overlay = null;
let state = null;
let labelClean = null;
let manualClean = null;
const past = [];
const future = [];
let tool = "positive";
let toolBeforeValidation = "positive";
let maskBeforeValidation = true;
let validation = false;
let leaving = false;
let spaceHeld = false;
let gesture = null;
const inflight = new Set();
const pngCache = new WeakMap();

// --- state and history ----------------------------------------------------------------------

function commit(next) {
  past.push(state);
  if (past.length > HISTORY_LIMIT) past.shift();
  future.length = 0;
  state = next;
  changed();
}

function undo() {
  if (!past.length) return;
  future.push(state);
  state = past.pop();
  changed();
}

function redo() {
  if (!future.length) return;
  past.push(state);
  state = future.pop();
  changed();
}

const labelDirty = () => state && (state.mask !== labelClean.mask || state.keypoints !== labelClean.keypoints);
const manualDirty = () => state && state.manual !== manualClean;

function sameKeypoints(a, b) {
  return a.length === b.length && a.every(([x, y], i) => Math.abs(x - b[i][0]) < 1e-6 && Math.abs(y - b[i][1]) < 1e-6);
}

/** Whether the shown label is the newest proposal, untouched (Accept then stores "accepted"). */
function isProposal() {
  return proposal !== null && state.mask.equals(proposal.mask) && sameKeypoints(state.keypoints, proposal.keypoints);
}

/** Refresh the canvas and the side panel after any change of `state`. */
function changed() {
  if (overlay.mask !== state.mask) overlay.paint(state.mask);
  showOutline();
  exposeState();
  stage.keypoints = validation ? state.manual : state.keypoints;
  stage.keypointStyle = validation ? "manual" : "keypoint";
  stage.dimKeypoints = !validation && state.maskEdited && !state.kpEdited;
  if (stage.selected >= stage.keypoints.length) stage.selected = -1;
  stage.points = state.session?.points ?? [];
  stage.box = state.session?.box ?? null;
  stage.requestRender();
  $("undo").disabled = !past.length;
  $("redo").disabled = !future.length;
  $("dirty").hidden = !labelDirty() && !manualDirty();
  renderKeypointList();
  renderManualCount();
  renderVerdictNote();
}

/** What the canvas shows, as data attributes: for people inspecting the page and for tests. */
function exposeState() {
  const data = stage.canvas.dataset;
  data.maskArea = String(state.mask.area());
  data.keypoints = JSON.stringify(state.keypoints.map(([x, y]) => [Math.round(x * 10) / 10, Math.round(y * 10) / 10]));
  data.manual = JSON.stringify(state.manual.map(([x, y]) => [Math.round(x * 10) / 10, Math.round(y * 10) / 10]));
  data.clicks = String(state.session?.points.length ?? 0);
  data.revision = String(revision);
  data.pending = String(inflight.size);
  data.outline = JSON.stringify(stage.polygons ?? []);
}

// --- side panel -----------------------------------------------------------------------------

function renderKeypointList() {
  const list = $("keypoint-list");
  const points = validation ? state.manual : state.keypoints;
  list.replaceChildren(...points.map(([x, y], i) => h("li", { class: i === stage.selected ? "selected" : "" },
    h("span", {}, `${x.toFixed(1)}, ${y.toFixed(1)}`),
    h("button", { type: "button", class: "quiet tiny-btn", title: "Remove this keypoint", onclick: () => deleteKeypoint(i) }, "×"))));
  if (!points.length) list.append(h("li", { class: "muted plain" }, validation ? "none placed yet" : "none"));
  if (stage.dimKeypoints) list.append(h("li", { class: "muted plain" }, "The mask changed: the keypoints are recomputed from it on save, unless you move one."));
}

function renderManualCount() {
  $("manual-count").textContent = `${state.manual.length} of ${K} placed`;
  $("save-validation").disabled = state.manual.length !== K || !manualDirty();
}

function renderVerdictNote() {
  const note = $("verdict-note");
  if (!isReviewer()) {
    note.textContent = `As ${ROLE} you save corrections; a reviewer accepts or rejects.`;
  } else if (!proposal) {
    note.textContent = "No proposal: Accept saves what you drew as corrected.";
  } else if (!isProposal()) {
    note.textContent = "The label shown differs from the proposal: Accept saves it as corrected.";
  } else {
    note.textContent = "Accept keeps the proposal as it is.";
  }
}

/** Why a frame ranks high in the queue, in words (see weldpool_core.active). */
const REASONS = {
  teacher_iou: "SAM2's own doubt about its mask",
  instability: "the mask changing when the prompts move slightly",
  disagreement: "the student disagreeing with the teacher",
  student_uncertainty: "the student's own doubt (unstable under small changes, or unlike what it learnt from)",
};

function renderFrameInfo() {
  $("frame-title").textContent = `Frame #${frame.id}`;
  const parts = [frame.original_name, `${frame.width}×${frame.height}`, `${frame.bit_depth}-bit`, `${frame.split} split`];
  if (frame.frame_index !== null) parts.push(`index ${frame.frame_index}`);
  $("frame-meta").textContent = parts.filter(Boolean).join(" · ");
  const pieces = [badge(frame.status)];
  if (revision) pieces.push(h("span", { class: "muted" }, ` revision ${revision}`));
  if (proposal) {
    const iou = proposal.scores?.sam2_iou;
    pieces.push(h("br"), h("span", { class: "muted", "data-testid": "proposal-source" }, `${sourceName(proposal)} proposal`, iou !== undefined && iou !== null ? ` · SAM2 IoU ${score(Number(iou))}` : ""));
    if (proposal.scores?.low_confidence) pieces.push(h("br"), h("span", { class: "warning" }, "SAM2 lost confidence here: correct this frame and propagate again from it."));
    if (frame.uncertainty !== null) {
      const reason = REASONS[frame.uncertainty_reason] ?? frame.uncertainty_reason;
      pieces.push(h("br"), h("span", { class: "uncertainty", "data-testid": "uncertainty-reason" },
        `uncertainty ${score(frame.uncertainty)}`, reason ? ` — mostly ${reason}` : ""));
    }
    if (proposal.scores?.warning) pieces.push(h("br"), h("span", { class: "warning" }, proposal.scores.warning));
  }
  $("frame-state").replaceChildren(...pieces);
  $("frame-state").dataset.status = frame.status;
}

async function loadHistory() {
  try {
    const rows = await api(`/frames/${FRAME_ID}/label/history`);
    const list = $("history");
    list.replaceChildren(...rows.slice().reverse().slice(0, 8).map((r) =>
      h("li", {}, `rev ${r.revision} · `, badge(r.status), ` · ${r.user ?? "?"} · ${formatDate(r.created_at)}`)));
    if (!rows.length) list.append(h("li", {}, "no label yet"));
  } catch { /* the history is a convenience */ }
}

// --- tools ----------------------------------------------------------------------------------

/** The tools that ask SAM2 for a mask: without its weights they are disabled and say why. */
const SAM2_TOOLS = new Set(["positive", "negative", "box"]);

/** Whether a tool can be used now: keypoints only while validating, SAM2's only with SAM2. */
const toolUsable = (name) => (validation ? name === "keypoint" : !(SAM2_PROBLEM && SAM2_TOOLS.has(name)));

function setTool(name) {
  if (!toolUsable(name)) {
    if (!validation) toast(SAM2_PROBLEM, "error");
    return;
  }
  tool = name;
  if (!validation) remember({ tool: name });
  for (const button of document.querySelectorAll("#tools .tool")) {
    button.classList.toggle("active", button.dataset.tool === name);
    button.setAttribute("aria-pressed", String(button.dataset.tool === name));
  }
  stage.canvas.dataset.tool = name;
  if (name !== "brush" && name !== "eraser") stage.cursor = null;
  stage.selectedVertex = null;
  showOutline();
  stage.requestRender();
}

const brushRadius = () => Number($("brush-size").value) / 2;

function setBrushSize(value) {
  const input = $("brush-size");
  input.value = String(Math.min(Number(input.max), Math.max(Number(input.min), value)));
  $("brush-size-value").textContent = input.value;
  remember({ brush: Number(input.value) });
  if (stage.cursor) { stage.cursor.radius = brushRadius(); stage.requestRender(); }
}

// --- what the reviewer set up stays from frame to frame (this browser) -------------------------

const PREFS_KEY = "weldpool.review";
const prefs = () => { try { return JSON.parse(localStorage.getItem(PREFS_KEY)) ?? {}; } catch { return {}; } };
function remember(values) {
  localStorage.setItem(PREFS_KEY, JSON.stringify({ ...prefs(), ...values }));
}

const DISPLAY = { brightness: "display-brightness", contrast: "display-contrast", gamma: "display-gamma", maskOpacity: "display-opacity" };
const DEFAULT_DISPLAY = { brightness: 1, contrast: 1, gamma: 1, maskOpacity: 1, keypoints: true, outlineOnly: false };

function applyDisplay(values) {
  stage.display = { ...DEFAULT_DISPLAY, ...values };
  for (const [key, id] of Object.entries(DISPLAY)) {
    $(id).value = String(stage.display[key]);
    $(`${id}-value`).textContent = Number(stage.display[key]).toFixed(2);
  }
  $("display-keypoints").checked = stage.display.keypoints;
  $("display-outline").checked = stage.display.outlineOnly;
  fillMask();
  for (const channel of document.querySelectorAll("#gamma-filter feComponentTransfer > *")) {
    channel.setAttribute("exponent", String(1 / stage.display.gamma)); // gamma > 1 brightens the mid-tones
  }
  stage.canvas.dataset.display = JSON.stringify(stage.display);
  remember({ display: stage.display });
  stage.requestRender();
}

function bindDisplay() {
  for (const [key, id] of Object.entries(DISPLAY)) {
    $(id).addEventListener("input", (event) => applyDisplay({ ...stage.display, [key]: Number(event.target.value) }));
  }
  $("display-keypoints").addEventListener("change", (event) => applyDisplay({ ...stage.display, keypoints: event.target.checked }));
  $("display-outline").addEventListener("change", (event) => applyDisplay({ ...stage.display, outlineOnly: event.target.checked }));
  $("display-reset").addEventListener("click", () => applyDisplay(DEFAULT_DISPLAY));
  applyDisplay(prefs().display ?? DEFAULT_DISPLAY);
}

/** End the click session: the next click starts from the mask shown now. */
function endSession() {
  if (state.session) commit({ ...state, session: null });
}

function addClick(x, y, positive) {
  const session = state.session ?? { points: [], box: null, base: state.mask.any() ? state.mask : null };
  if (session.points.length >= 64) { toast("At most 64 clicks; press Esc to start a new click session.", "error"); return; }
  commit({ ...state, session: { ...session, points: [...session.points, { x, y, positive }] } });
  segment(state);
}

function setBox(box) {
  const session = state.session ?? { points: [], box: null, base: state.mask.any() ? state.mask : null };
  commit({ ...state, session: { ...session, box } });
  segment(state);
}

function pngOf(mask) {
  if (!pngCache.has(mask)) pngCache.set(mask, mask.toPng());
  return pngCache.get(mask);
}

/** Ask the segment endpoint for `target`'s click session; the answer becomes its mask. */
function segment(target) {
  const run = (async () => {
    const { points, box, base } = target.session;
    const body = { points: points.map((p) => ({ x: p.x, y: p.y, positive: p.positive })) };
    if (box) body.box = box;
    if (base) body.mask_png = await pngOf(base);
    const answer = await api(`/frames/${FRAME_ID}/segment`, { method: "POST", json: body });
    const mask = await Mask.fromPng(answer.mask_png, frame.width, frame.height);
    target.mask = mask;
    target.maskEdited = true;
    $("last-click").textContent = `mask in ${Math.round(answer.elapsed_ms)} ms · SAM2 IoU ${score(answer.score)}`;
    if (target === state) changed();
  })();
  track(run);
}

/** Count `run` as pending (saving waits for it; the page shows "segmenting…"), toast its error. */
function track(run, onError = () => {}) {
  inflight.add(run);
  $("busy").hidden = false;
  exposeState();
  run.catch((error) => { toast(error.message, "error"); onError(); }).finally(() => {
    inflight.delete(run);
    $("busy").hidden = inflight.size === 0;
    exposeState();
  });
}

// --- the outline as polygons (tool 7): drag, add and remove vertices -------------------------
//
// The mask shown is traced once into polygons (outer boundaries and holes, by the server with
// OpenCV); an edit makes a new state whose outline is the edited polygons, and the server fills
// them back into the mask. Undo and redo restore mask and outline together.

/** Show the outline of the current mask while the polygon tool is on (tracing it if needed). */
function showOutline() {
  const outline = state?.outline;
  // Current: traced from this mask, or being traced or filled from it (pending).
  const current = outline && (outline.mask === state.mask || (outline.mask === null && outline.base === state.mask));
  stage.polygons = tool === "polygon" && !validation && current ? outline.polygons : null;
  if (tool === "polygon" && !validation && !current && state) traceOutline(state);
  if (stage.selectedVertex && !stage.polygons?.[stage.selectedVertex.polygon]?.points[stage.selectedVertex.index]) {
    stage.selectedVertex = null;
  }
}

function traceOutline(target) {
  const mask = target.mask;
  target.outline = { mask: null, base: mask, polygons: [] }; // pending: traced once
  const run = (async () => {
    const answer = mask.any()
      ? await api(`/frames/${FRAME_ID}/outline`, { method: "POST", json: { mask_png: await pngOf(mask), tolerance: OUTLINE_TOLERANCE } })
      : { polygons: [] };
    target.outline = { mask, polygons: answer.polygons };
    if (target === state) { showOutline(); exposeState(); stage.requestRender(); }
  })();
  track(run, () => { target.outline = null; });
}

/** A new state whose outline is `change`d (a deep copy); its mask follows from the server. */
function editOutline(change) {
  const polygons = state.outline.polygons.map((p) => ({ hole: p.hole, points: p.points.map((q) => [...q]) }));
  change(polygons);
  commit({ ...state, outline: { mask: null, base: state.mask, polygons }, maskEdited: true, session: null });
  return state;
}

function fillOutline(target) {
  const run = (async () => {
    const answer = await api(`/frames/${FRAME_ID}/outline/mask`, { method: "POST", json: { polygons: target.outline.polygons } });
    const mask = await Mask.fromPng(answer.mask_png, frame.width, frame.height);
    target.mask = mask;
    target.outline = { mask, polygons: target.outline.polygons };
    if (target === state) changed();
  })();
  track(run, () => { if (target === state) undo(); });
}

/** Remove a vertex; a polygon left with fewer than 3 goes (an outer one with its holes). */
function removeVertex({ polygon, index }) {
  const target = editOutline((polygons) => {
    polygons[polygon].points.splice(index, 1);
    if (polygons[polygon].points.length >= 3) return;
    let end = polygon + 1;
    if (!polygons[polygon].hole) while (end < polygons.length && polygons[end].hole) end++;
    polygons.splice(polygon, end - polygon);
  });
  stage.selectedVertex = null;
  fillOutline(target);
}

function deleteKeypoint(index) {
  if (validation) {
    commit({ ...state, manual: state.manual.filter((_, i) => i !== index) });
  } else {
    commit({ ...state, keypoints: state.keypoints.filter((_, i) => i !== index), kpEdited: true });
  }
  stage.selected = -1;
  changed();
}

// --- pointer gestures on the canvas ---------------------------------------------------------

function local(event) {
  const rect = stage.canvas.getBoundingClientRect();
  return [event.clientX - rect.left, event.clientY - rect.top];
}

function clampToFrame([x, y]) {
  return [Math.min(frame.width, Math.max(0, x)), Math.min(frame.height, Math.max(0, y))];
}

function onPointerDown(event) {
  const [sx, sy] = local(event);
  stage.canvas.focus();
  stage.canvas.setPointerCapture(event.pointerId);
  const [x, y] = stage.toImage(sx, sy);
  const inside = x >= 0 && y >= 0 && x <= frame.width && y <= frame.height;
  gesture = { kind: "pan", sx, sy, lastX: sx, lastY: sy, moved: 0 };
  if (event.button === 1 || spaceHeld) return;
  if (ruler.active) { // the ruler takes the clicks while it is out; elsewhere a drag pans
    if (event.button === 0) gesture = ruler.pointerDown(sx, sy, x, y, inside) ?? gesture;
    return;
  }
  if (tool === "keypoint") {
    const index = stage.keypointAt(sx, sy);
    const key = validation ? "manual" : "keypoints";
    if (event.button === 2) {
      gesture = null;
      if (index >= 0) deleteKeypoint(index);
      return;
    }
    if (index < 0) {
      if (!inside) return;
      if (validation && state.manual.length >= K) {
        toast(`All ${K} keypoints are placed; drag one to move it, or remove one first.`, "info");
        gesture = null;
        return;
      }
      commit({ ...state, [key]: [...state[key].map((p) => [...p]), [x, y]], kpEdited: state.kpEdited || !validation });
    }
    stage.selected = index >= 0 ? index : state[key].length - 1;
    // Selecting an existing keypoint is no edit; moving it is (committed on the first move).
    gesture = { kind: "keypoint", key, index: stage.selected, committed: index < 0 };
    changed();
    return;
  }
  if (tool === "polygon" && stage.polygons && state.outline?.mask) {
    const vertex = stage.vertexAt(sx, sy);
    if (vertex && event.button === 2) { gesture = null; removeVertex(vertex); return; }
    if (vertex && event.button === 0) {
      stage.selectedVertex = vertex;
      gesture = { kind: "vertex", ...vertex, committed: false };
      stage.requestRender();
      return;
    }
    const edge = event.button === 0 ? stage.edgeAt(sx, sy) : null;
    if (edge) { // a new vertex on the edge, dragged from here
      editOutline((polygons) => polygons[edge.polygon].points.splice(edge.index, 0, [edge.x, edge.y]));
      stage.selectedVertex = { polygon: edge.polygon, index: edge.index };
      gesture = { kind: "vertex", polygon: edge.polygon, index: edge.index, committed: true };
      showOutline();
      stage.requestRender();
      return;
    }
    return; // elsewhere: a drag pans
  }
  if (!inside && tool !== "box") return;
  if (tool === "brush" || tool === "eraser") {
    if (event.button !== 0) return;
    commit({ ...state, mask: state.mask.clone(), maskEdited: true, session: null });
    const rect = state.mask.stamp(x, y, brushRadius(), tool === "brush" ? 1 : 0);
    overlay.paint(state.mask, rect);
    gesture = { kind: "brush", x, y, value: tool === "brush" ? 1 : 0 };
    stage.requestRender();
  } else if (tool === "box") {
    if (event.button !== 0) return;
    const [cx, cy] = clampToFrame([x, y]);
    gesture = { kind: "box", x: cx, y: cy };
    stage.draft = [cx, cy, cx, cy];
  } else {
    const positive = (tool === "positive") !== (event.shiftKey || event.button === 2);
    gesture = { kind: "click", sx, sy, lastX: sx, lastY: sy, moved: 0, x, y, positive };
  }
}

function onPointerMove(event) {
  const [sx, sy] = local(event);
  const [x, y] = stage.toImage(sx, sy);
  if (tool === "brush" || tool === "eraser") {
    stage.cursor = { x, y, radius: brushRadius(), erase: tool === "eraser" };
    stage.requestRender();
  }
  if (!gesture) {
    stage.canvas.classList.toggle("over-keypoint", tool === "keypoint" && stage.keypointAt(sx, sy) >= 0);
    stage.canvas.classList.toggle("over-vertex", tool === "polygon" && stage.vertexAt(sx, sy) !== null);
    stage.canvas.classList.toggle("over-edge", tool === "polygon" && !stage.vertexAt(sx, sy) && stage.edgeAt(sx, sy) !== null);
    return;
  }
  if (gesture.kind === "click") {
    gesture.moved = Math.max(gesture.moved, Math.hypot(sx - gesture.sx, sy - gesture.sy));
    if (gesture.moved > 4) gesture.kind = "pan";
  }
  if (gesture.kind === "pan") {
    stage.panBy(sx - gesture.lastX, sy - gesture.lastY);
    gesture.lastX = sx;
    gesture.lastY = sy;
  } else if (gesture.kind === "brush") {
    const rect = state.mask.line(gesture.x, gesture.y, x, y, brushRadius(), gesture.value);
    overlay.paint(state.mask, rect);
    gesture.x = x;
    gesture.y = y;
    stage.requestRender();
  } else if (gesture.kind === "box") {
    const [cx, cy] = clampToFrame([x, y]);
    stage.draft = [Math.min(gesture.x, cx), Math.min(gesture.y, cy), Math.max(gesture.x, cx), Math.max(gesture.y, cy)];
    stage.requestRender();
  } else if (gesture.kind === "vertex") {
    if (!gesture.committed) {
      gesture.committed = true;
      editOutline(() => {});
      showOutline();
    }
    state.outline.polygons[gesture.polygon].points[gesture.index] = clampToFrame([x, y]);
    stage.requestRender();
  } else if (gesture.kind === "ruler") {
    ruler.move(gesture.index, x, y);
  } else if (gesture.kind === "keypoint") {
    if (!gesture.committed) {
      gesture.committed = true;
      commit({ ...state, [gesture.key]: state[gesture.key].map((p) => [...p]), kpEdited: state.kpEdited || !validation });
    }
    state[gesture.key][gesture.index] = clampToFrame([x, y]);
    stage.requestRender();
  }
}

function onPointerUp() {
  const done = gesture;
  gesture = null;
  if (!done) return;
  if (done.kind === "click") {
    addClick(done.x, done.y, done.positive);
  } else if (done.kind === "box") {
    const box = stage.draft;
    stage.draft = null;
    if (box && box[2] - box[0] >= 2 && box[3] - box[1] >= 2) setBox(box);
    else stage.requestRender();
  } else if (done.kind === "vertex") {
    if (done.committed) fillOutline(state);
  } else if (done.kind === "brush" || done.kind === "keypoint") {
    changed();
  }
}

// --- verdicts -------------------------------------------------------------------------------

async function verdictBody(kind, baseRevision) {
  const from = proposal ? { proposal_id: proposal.id } : {};
  if (kind === "reject") return { status: "rejected", base_revision: baseRevision, ...from };
  if (kind === "accept" && isProposal()) return { status: "accepted", base_revision: baseRevision, ...from };
  const body = { status: "corrected", base_revision: baseRevision, mask_png: await state.mask.toPng(), ...from };
  const stale = state.maskEdited && !state.kpEdited;
  if (!stale && state.keypoints.length) body.keypoints = state.keypoints;
  return body;
}

async function saveLabel(kind, baseRevision = revision) {
  if (validation) toggleValidation();
  await Promise.allSettled([...inflight]);
  const body = await verdictBody(kind, baseRevision);
  let label;
  try {
    label = await api(`/frames/${FRAME_ID}/label`, { method: "PUT", json: body });
  } catch (error) {
    if (error instanceof ApiError && error.status === 409) return showConflict(kind, error);
    toast(error.message, "error");
    return;
  }
  revision = label.revision;
  labelStatus = label.status;
  frame.status = label.status;
  const keypoints = label.keypoints ?? state.keypoints;
  state = { ...state, keypoints, maskEdited: false, kpEdited: false, session: null };
  labelClean = state;
  changed();
  renderFrameInfo();
  renderPropagate();
  loadHistory();
  toast(`Saved as ${label.status} (revision ${label.revision}).`, "ok");
  if ($("advance").checked) await goNext({ afterSave: true });
}

/** Someone saved first: say who and when, show their label beside mine, let the reviewer pick. */
async function showConflict(kind, error) {
  const current = error.body?.revision ?? 0;
  const by = error.body?.updated_by ?? "someone else";
  $("conflict-text").textContent = `${by} saved this frame's label while you were working on it (it is now at revision ${current}). Reload to take theirs (your changes are dropped), or overwrite it with yours.`;
  const dialog = $("conflict");
  $("conflict-overwrite").onclick = () => { dialog.close(); saveLabel(kind, current); };
  $("conflict-reload").onclick = () => { dialog.close(); leaving = true; location.reload(); };
  $("conflict-cancel").onclick = () => dialog.close();
  const mine = kind === "reject" ? null : state.mask;
  drawPreview($("conflict-mine"), mine, "#00e6ff");
  $("conflict-mine-text").textContent = kind === "reject" ? "Yours: rejected (no pool)" : `Yours: ${kind === "accept" && isProposal() ? "accepted" : "corrected"} · ${mine.area()} px`;
  $("conflict-theirs-text").textContent = "Theirs: loading…";
  dialog.showModal();
  try {
    const theirs = await api(`/frames/${FRAME_ID}/label`);
    const mask = theirs.mask_png ? await Mask.fromPng(theirs.mask_png, frame.width, frame.height) : null;
    drawPreview($("conflict-theirs"), mask, "#ff922b");
    let differs = "";
    if (mask && mine) {
      let n = 0;
      for (let i = 0; i < mask.data.length; i++) n += mask.data[i] !== mine.data[i];
      differs = ` · differs from yours in ${n} px`;
    }
    $("conflict-theirs-text").textContent = `Theirs: ${theirs.status} by ${theirs.updated_by ?? "?"}, ${formatDate(theirs.updated_at)}${mask ? ` · ${mask.area()} px` : ""}${differs}`;
  } catch (problem) {
    $("conflict-theirs-text").textContent = `Theirs could not be loaded: ${problem.message}`;
  }
}

/** The frame with a mask's outline and a light fill, scaled into a small canvas. */
function drawPreview(canvas, mask, colour) {
  const scale = Math.min(canvas.width / frame.width, canvas.height / frame.height);
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  ctx.drawImage(stage.image, 0, 0, frame.width * scale, frame.height * scale);
  if (!mask) return;
  const layer = new MaskOverlay(frame.width, frame.height);
  layer.paint(mask);
  ctx.globalAlpha = 0.9;
  ctx.drawImage(layer.canvas, 0, 0, frame.width * scale, frame.height * scale);
  ctx.globalAlpha = 1;
  ctx.strokeStyle = colour;
  ctx.lineWidth = 3;
  ctx.strokeRect(1.5, 1.5, frame.width * scale - 3, frame.height * scale - 3);
}

async function saveValidation() {
  try {
    const saved = await api(`/frames/${FRAME_ID}/validation-keypoints`, { method: "PUT", json: { keypoints: state.manual } });
    manualClean = state.manual;
    frame.split = "validation";
    renderFrameInfo();
    $("validation-state").textContent = `Saved ${saved.keypoints.length} keypoints by hand (${formatDate(saved.updated_at)}); this frame is in the validation split.`;
    toast("Validation keypoints saved.", "ok");
    changed();
  } catch (error) {
    toast(error.message, "error");
  }
}

/** Each tool button enabled when usable; SAM2's say why they are not. */
function enableTools() {
  for (const button of document.querySelectorAll("#tools .tool")) {
    button.disabled = !toolUsable(button.dataset.tool);
    if (SAM2_PROBLEM && SAM2_TOOLS.has(button.dataset.tool)) button.title = SAM2_PROBLEM;
  }
}

function toggleValidation() {
  validation = !validation;
  document.body.classList.toggle("validating", validation);
  $("validation-toggle").setAttribute("aria-pressed", String(validation));
  $("validation-toggle").classList.toggle("active", validation);
  $("validation-panel").hidden = !validation;
  enableTools();
  stage.selected = -1;
  if (validation) {
    toolBeforeValidation = tool;
    maskBeforeValidation = $("show-mask").checked;
    setMaskVisible(false);
    setTool("keypoint");
  } else {
    setMaskVisible(maskBeforeValidation);
    setTool(toolBeforeValidation);
  }
  changed();
}

// --- the queue ------------------------------------------------------------------------------

const SKIPPED_KEY = "weldpool.skipped";
const skipped = () => new Set(JSON.parse(sessionStorage.getItem(SKIPPED_KEY) ?? "[]"));

async function queueIds() {
  const params = new URLSearchParams(CONTEXT);
  params.set("limit", "500");
  params.delete("offset");
  const page = await api(`/frames?${params}`);
  return { ids: page.items.map((f) => f.id), total: page.total, ordering: page.ordering };
}

async function goNext({ afterSave = false } = {}) {
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
  leaving = true;
  location.href = `/frames/${next}?${CONTEXT}`;
}

async function showQueuePosition() {
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

// --- overlays -------------------------------------------------------------------------------

/** The mask is drawn as its outline only when asked, and always over the heatmap (readable). */
function fillMask() {
  overlay.setFilled(!stage.display.outlineOnly && !stage.showHeatmap);
  stage.canvas.dataset.maskFill = String(overlay.filled);
  stage.requestRender();
}

function setMaskVisible(on) {
  $("show-mask").checked = on;
  stage.showMask = on;
  stage.requestRender();
}

async function setHeatmapVisible(on) {
  $("show-heatmap").checked = on;
  stage.showHeatmap = on;
  fillMask();
  if (on && !stage.heatmap && proposal) {
    const image = new Image();
    image.src = `/api/v1/frames/${FRAME_ID}/proposal/heatmap.png?proposal_id=${proposal.id}`;
    try { await image.decode(); stage.heatmap = image; stage.canvas.dataset.heatmap = "loaded"; } catch { toast("The heatmap could not be loaded.", "error"); }
  }
  stage.requestRender();
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
  list.replaceChildren(...proposals.map((item) => {
    const iou = item.scores?.sam2_iou;
    const detail = iou !== undefined && iou !== null ? ` · SAM2 IoU ${score(Number(iou))}` : "";
    return h("button", {
      type: "button",
      class: `source${proposal && item.id === proposal.id ? " shown" : ""}`,
      "aria-pressed": String(Boolean(proposal && item.id === proposal.id)),
      "data-testid": "proposal-option",
      "data-proposal-id": String(item.id),
      title: `${sourceName(item)}, ${formatDate(item.created_at)}`,
      onclick: () => switchProposal(item.id),
    }, sourceName(item), h("span", { class: "muted" }, detail), item.chosen ? h("span", { class: "chosen" }, " ★ chosen") : "");
  }));
  $("proposals-section").hidden = proposals.length === 0;
  $("policy-reason").textContent = proposals.length > 1 ? policyReason : "";
  $("rerun-teacher").hidden = proposals.length === 0;
}

/** Show another proposal of the frame: it replaces the working mask (undoable once edited). */
async function switchProposal(id) {
  if (proposal && proposal.id === id) return;
  let body;
  try {
    body = await api(`/frames/${FRAME_ID}/proposal?proposal_id=${id}`);
  } catch (error) { toast(error.message, "error"); return; }
  const mask = await Mask.fromPng(body.mask_png, frame.width, frame.height);
  proposal = { ...body, mask };
  stage.heatmap = null;
  if (stage.showHeatmap) setHeatmapVisible(true);
  const next = { ...state, mask, keypoints: (body.keypoints ?? []).map((p) => [...p]), maskEdited: false, kpEdited: false, session: null };
  if (revision === 0 && !labelDirty()) { state = next; labelClean = next; changed(); }
  else commit(next);
  renderProposals();
  renderFrameInfo();
  stage.requestRender();
}

function cycleProposal() {
  if (proposals.length < 2) return;
  const index = proposals.findIndex((item) => proposal && item.id === proposal.id);
  switchProposal(proposals[(index + 1) % proposals.length].id);
}

function deleteSelected() {
  if (tool === "polygon" && stage.selectedVertex && state.outline?.mask) removeVertex(stage.selectedVertex);
  else if (stage.selected >= 0) deleteKeypoint(stage.selected);
}

// --- keyboard -------------------------------------------------------------------------------

const TOOL_KEYS = { 1: "positive", 2: "negative", 3: "box", 4: "brush", 5: "eraser", 6: "keypoint", 7: "polygon" };

function onKey(event) {
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
    spaceHeld = true;
    stage.canvas.classList.add("panning");
    event.preventDefault();
    return;
  }
  if (TOOL_KEYS[key]) { setTool(TOOL_KEYS[key]); return; }
  const actions = {
    "[": () => setBrushSize(Number($("brush-size").value) - 4),
    "]": () => setBrushSize(Number($("brush-size").value) + 4),
    a: () => !$("accept").disabled && saveLabel("accept"),
    r: () => !$("reject").disabled && saveLabel("reject"),
    s: () => saveLabel("correct"),
    n: () => goNext(),
    m: () => setMaskVisible(!stage.showMask),
    h: () => setHeatmapVisible(!stage.showHeatmap),
    f: () => stage.fit(),
    v: () => toggleValidation(),
    l: () => !$("measure-scale").disabled && ruler.toggle(),
    p: () => cycleProposal(),
    escape: () => { stage.draft = null; gesture = null; if (ruler.active) ruler.toggle(); else endSession(); },
    delete: () => deleteSelected(),
    backspace: () => deleteSelected(),
  };
  if (actions[key]) { event.preventDefault(); actions[key](); }
}

// --- loading --------------------------------------------------------------------------------

async function optional(path) {
  try { return await api(path); } catch (error) {
    if (error instanceof ApiError && error.status === 404) return null;
    throw error;
  }
}

function loadImage(url) {
  const image = new Image();
  image.src = url;
  return image.decode().then(() => image);
}

function fail(message) {
  $("stage-message").textContent = message;
  $("stage-message").classList.add("error");
  for (const button of document.querySelectorAll(".verdict button, .toolbar button")) button.disabled = true;
}

function bindControls() {
  const canvas = stage.canvas;
  canvas.addEventListener("pointerdown", onPointerDown);
  canvas.addEventListener("pointermove", onPointerMove);
  canvas.addEventListener("pointerup", onPointerUp);
  canvas.addEventListener("pointercancel", onPointerUp);
  canvas.addEventListener("pointerleave", () => { if (stage.cursor) { stage.cursor = null; stage.requestRender(); } });
  canvas.addEventListener("contextmenu", (event) => event.preventDefault());
  canvas.addEventListener("wheel", (event) => {
    event.preventDefault();
    const [sx, sy] = local(event);
    stage.zoomAt(Math.exp(-event.deltaY * 0.0015), sx, sy);
  }, { passive: false });
  stage.onViewChange = () => {
    $("zoom-level").textContent = `${Math.round(stage.scale * 100)} %`;
    stage.canvas.dataset.view = JSON.stringify({ scale: stage.scale, tx: stage.tx, ty: stage.ty });
  };
  stage.onViewChange();
  // Tool buttons hand the keyboard back to the canvas (Space pans there, it must not click).
  for (const button of document.querySelectorAll("#tools .tool")) {
    button.addEventListener("click", () => { setTool(button.dataset.tool); stage.canvas.focus(); });
  }
  $("brush-size").addEventListener("input", (event) => setBrushSize(Number(event.target.value)));
  $("undo").addEventListener("click", undo);
  $("redo").addEventListener("click", redo);
  $("fit").addEventListener("click", () => stage.fit());
  $("show-mask").addEventListener("change", (event) => setMaskVisible(event.target.checked));
  $("show-heatmap").addEventListener("change", (event) => setHeatmapVisible(event.target.checked));
  $("accept").addEventListener("click", () => saveLabel("accept"));
  $("reject").addEventListener("click", () => saveLabel("reject"));
  $("save").addEventListener("click", () => saveLabel("correct"));
  $("next").addEventListener("click", () => goNext());
  $("validation-toggle").addEventListener("click", toggleValidation);
  $("save-validation").addEventListener("click", saveValidation);
  $("clear-validation").addEventListener("click", () => state.manual.length && commit({ ...state, manual: [] }));
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
    if (event.key === " ") { spaceHeld = false; stage.canvas.classList.remove("panning"); }
  });
  window.addEventListener("beforeunload", (event) => {
    if (!leaving && (labelDirty() || manualDirty())) { event.preventDefault(); event.returnValue = ""; }
  });
  if (!isReviewer()) {
    for (const id of ["accept", "reject"]) {
      $(id).disabled = true;
      $(id).title = "Accepting and rejecting need the reviewer role; save as corrected instead.";
    }
  }
}

// --- propagation through the weld run -------------------------------------------------------

function renderPropagate() {
  const button = $("propagate");
  const reviewed = labelStatus === "accepted" || labelStatus === "corrected";
  button.disabled = !frame.sequence_id || !reviewed || Boolean(SAM2_PROBLEM) || !isReviewer();
  button.title = SAM2_PROBLEM
    || (!isReviewer() ? "A reviewer propagates: it writes proposals over the whole run."
      : !frame.sequence_id ? "This frame belongs to no weld run."
      : reviewed ? "SAM2's video model carries this frame's reviewed mask to the run's other frames"
        : "Accept or correct this frame first: propagation starts from a reviewed mask.");
}

function timelineNote() {
  $("propagate-note").replaceChildren(...(frame.sequence_id
    ? [h("a", { href: `/sequences/${frame.sequence_id}`, "data-testid": "timeline-link" }, "The run's timeline"), " — geometry and confidence per frame."]
    : []));
}

async function propagateFromHere() {
  const threshold = Math.min(1, Math.max(0, Number($("propagate-threshold").value) || 0));
  const direction = $("propagate-direction").value;
  const body = { from_frame_ids: [FRAME_ID], direction, threshold };
  const until = $("propagate-until").value.trim();
  if (direction !== "both" && until !== "") body.until_frame_index = Math.max(0, Math.round(Number(until)));
  try {
    const job = await jobFromButton($("propagate"), () => api(`/sequences/${frame.sequence_id}/propagate`, { method: "POST", json: body }), "Propagating");
    if (job.status !== "succeeded") throw new Error(`The propagation job ${job.status}: ${job.error ?? job.message ?? ""}`);
    $("propagate-note").replaceChildren(`${job.message}. `, h("a", { href: `/sequences/${frame.sequence_id}`, "data-testid": "timeline-link" }, "Open the run's timeline"), ".");
    toast(`Propagation done: ${job.message}.`, "ok");
  } catch (error) {
    toast(error.message, "error");
  } finally {
    renderPropagate();
  }
}

async function runTeacher(force) {
  const button = $(force ? "rerun-teacher" : "run-teacher");
  const text = button.textContent;
  button.disabled = true;
  try {
    const { job_id: jobId } = await api("/teacher/runs", { method: "POST", json: { frame_ids: [FRAME_ID], force } });
    const job = await waitForJob(jobId, (j) => { button.textContent = `Teacher: ${Math.round(j.progress * 100)} %`; });
    if (job.status !== "succeeded") throw new Error(`The teacher job ${job.status}: ${job.error ?? ""}`);
    if (labelDirty() || manualDirty()) toast("The proposal is ready; save or undo your changes, then reload.", "info");
    else { leaving = true; location.reload(); }
  } catch (error) {
    toast(error.message, "error");
    button.disabled = false;
    button.textContent = text;
  }
}

async function start() {
  const imageUrl = `/api/v1/frames/${FRAME_ID}/image?variant=display`;
  const image = loadImage(imageUrl);
  image.catch(() => {});
  let detail, proposalBody, label, manual, listing;
  try {
    // The frame says what it has, so nothing absent is asked for (no 404s in the log).
    detail = await api(`/frames/${FRAME_ID}`);
    [proposalBody, label, manual, listing] = await Promise.all([
      detail.proposal ? optional(`/frames/${FRAME_ID}/proposal`) : null,
      detail.label ? optional(`/frames/${FRAME_ID}/label`) : null,
      detail.has_validation_keypoints ? optional(`/frames/${FRAME_ID}/validation-keypoints`) : null,
      detail.proposal ? optional(`/frames/${FRAME_ID}/proposals`) : null,
    ]);
  } catch (error) {
    fail(error.message);
    return;
  }
  frame = detail;
  const { width, height } = frame;
  const [picture, proposalMask, labelMask] = await Promise.all([
    image.catch(() => null),
    proposalBody ? Mask.fromPng(proposalBody.mask_png, width, height) : null,
    label?.mask_png ? Mask.fromPng(label.mask_png, width, height) : null,
  ]);
  if (!picture) { fail(`The image of frame ${FRAME_ID} could not be loaded.`); return; }
  if (proposalBody) proposal = { ...proposalBody, mask: proposalMask };
  proposals = listing?.items ?? [];
  policyReason = listing?.policy?.reason ?? "";
  revision = label?.revision ?? 0;
  labelStatus = label?.status ?? null;

  stage = new Stage($("frame-canvas"), width, height);
  stage.image = picture;
  overlay = new MaskOverlay(width, height);
  stage.overlay = overlay;
  const keypoints = (labelMask ? label.keypoints : proposal?.keypoints) ?? [];
  state = {
    mask: labelMask ?? proposal?.mask ?? new Mask(width, height),
    keypoints: keypoints.map((p) => [...p]),
    manual: (manual?.keypoints ?? []).map((p) => [...p]),
    session: null,
    outline: null,
    maskEdited: false,
    kpEdited: false,
  };
  labelClean = state;
  manualClean = state.manual;
  if (manual) $("validation-state").textContent = `${manual.keypoints.length} keypoints placed by hand (${formatDate(manual.updated_at)}).`;
  $("no-proposal").hidden = proposal !== null || revision > 0; // reviewed: nothing to propose
  $("teacher-error").hidden = !frame.teacher_error;
  $("teacher-error").textContent = frame.teacher_error ? `The teacher's last run failed here: ${frame.teacher_error}` : "";
  $("show-heatmap").disabled = proposal === null;
  $("stage-message").hidden = true;
  ruler = new ScaleRuler(stage, frame);
  ruler.load();
  bindControls();
  renderProposals();
  renderPropagate();
  timelineNote();
  bindDisplay();
  const saved = prefs();
  if (saved.brush) setBrushSize(saved.brush);
  enableTools();
  const start = Object.values(TOOL_KEYS).includes(saved.tool) ? saved.tool : "positive";
  setTool(toolUsable(start) ? start : "brush");
  renderFrameInfo();
  changed();
  stage.render();
  stage.canvas.dataset.ready = "1";
  document.body.dataset.ready = "1";
  performance.mark("weldpool:interactive");
  showQueuePosition();
  loadHistory();
}

start();
