// The editing tools: SAM2 clicks and boxes through the segment endpoint, brush and eraser,
// the outline as polygons, and the pointer gestures on the canvas. Each works on the edited
// layer's mask (layers.js): the pool's or another class's object; a points class's layer takes
// its clicks as named points (points.js).

import { ApiError, SAM2_PROBLEM, api } from "../api.js";
import { score } from "../format.js";
import { toast } from "../ui.js";
import { remember } from "./display.js";
import { commit, exposeState, undo } from "./history.js";
import { copyPoints, deleteKeypoint, orderCentre, withPoint } from "./keypoints.js";
import { POOL, kindOf, maskOf, overlayOf, activeObject, setMaskIn, withMask } from "./layers.js";
import { Mask } from "./mask.js";
import { $, FRAME_ID, K, OUTLINE_TOLERANCE } from "./page.js";
import { pointsDown, pointsMove } from "./points.js";
import { S, changed } from "./state.js";

// --- tools ----------------------------------------------------------------------------------

/** The tools that ask SAM2 for a mask: without its weights they are disabled and say why. */
export const SAM2_TOOLS = new Set(["positive", "negative", "box"]);

/** Whether a tool can be used now: keypoints only while validating, SAM2's only with SAM2;
 *  a points class's layer takes clicks as its points, whatever the tool. */
export const toolUsable = (name) => (S.validation ? name === "keypoint" : !(SAM2_PROBLEM && SAM2_TOOLS.has(name)));
/** The overlay the edited layer's mask is painted on. */
const activeOverlay = () => (S.layer === POOL ? S.overlay : overlayOf(activeObject()));

export function setTool(name) {
  if (!toolUsable(name)) {
    if (!S.validation) toast(SAM2_PROBLEM, "error");
    return;
  }
  S.tool = name;
  if (!S.validation) remember({ tool: name });
  for (const button of document.querySelectorAll("#tools .tool")) {
    button.classList.toggle("active", button.dataset.tool === name);
    button.setAttribute("aria-pressed", String(button.dataset.tool === name));
  }
  S.stage.canvas.dataset.tool = name;
  $("outline-tolerance-group").hidden = name !== "polygon"; // in the brush size's place
  $("brush-size").closest("label").hidden = name === "polygon";
  if (name !== "brush" && name !== "eraser") S.stage.cursor = null;
  S.stage.selectedVertex = null;
  S.stage.newPolygon = null;
  showOutline();
  S.stage.requestRender();
}

/** The polygon tool's tolerance (px): how far its outline may cut the mask's corners. */
export function outlineTolerance() {
  const value = Number($("outline-tolerance").value);
  return Number.isFinite(value) ? Math.min(20, Math.max(0, value)) : OUTLINE_TOLERANCE;
}

/** A new tolerance: the current mask's outline traced again with it. */
export function setOutlineTolerance() {
  if (S.edit && S.edit.outline?.mask === maskOf(S.edit)) S.edit.outline = null; // a settled trace: again
  showOutline();
  S.stage.requestRender();
}

export const brushRadius = () => Number($("brush-size").value) / 2;

export function setBrushSize(value) {
  const input = $("brush-size");
  input.value = String(Math.min(Number(input.max), Math.max(Number(input.min), value)));
  $("brush-size-value").textContent = input.value;
  remember({ brush: Number(input.value) });
  if (S.stage.cursor) { S.stage.cursor.radius = brushRadius(); S.stage.requestRender(); }
}

/** End the click session: the next click starts from the mask shown now. */
export function endSession() {
  if (S.edit.session) commit({ ...S.edit, session: null });
}

/** The click session on the edited layer (a session on another layer ends with this one). */
function sessionHere() {
  if (S.edit.session?.layer === S.layer) return S.edit.session;
  const mask = maskOf(S.edit);
  return { points: [], box: null, base: mask.any() ? mask : null, layer: S.layer };
}

export function addClick(x, y, positive) {
  const session = sessionHere();
  if (session.points.length >= 64) { toast("At most 64 clicks; press Esc to start a new click session.", "error"); return; }
  commit({ ...S.edit, session: { ...session, points: [...session.points, { x, y, positive }] } });
  segment(S.edit);
}

export function setBox(box) {
  const session = sessionHere();
  commit({ ...S.edit, session: { ...session, box } });
  segment(S.edit);
}

export function pngOf(mask) {
  if (!S.pngCache.has(mask)) S.pngCache.set(mask, mask.toPng());
  return S.pngCache.get(mask);
}

/** The stored mask `mask` is, named as the server knows it (the proposal shown, or the label
 *  as loaded): a click then sends no PNG. Null for a mask drawn here. */
function storedMask(mask) {
  if (S.proposal && mask === S.proposal.mask) return { proposal_id: S.proposal.id };
  if (S.loadedLabel && mask === S.loadedLabel.mask) return { label_revision: S.loadedLabel.revision };
  return null;
}

/** Ask the segment endpoint for `target`'s click session; the answer becomes its mask. */
export function segment(target) {
  const run = (async () => {
    const { points, box, base } = target.session;
    const body = { points: points.map((p) => ({ x: p.x, y: p.y, positive: p.positive })) };
    if (box) body.box = box;
    const named = base ? storedMask(base) : null;
    if (named) body.mask_from = named;
    else if (base) body.mask_png = await pngOf(base);
    let answer;
    try {
      answer = await api(`/frames/${FRAME_ID}/segment`, { method: "POST", json: body });
    } catch (error) {
      if (!named || !(error instanceof ApiError && error.status === 409)) throw error;
      S.loadedLabel = null; // the label moved on meanwhile: send what this page shows
      delete body.mask_from;
      body.mask_png = await pngOf(base);
      answer = await api(`/frames/${FRAME_ID}/segment`, { method: "POST", json: body });
    }
    const mask = await Mask.fromPng(answer.mask_png, S.frame.width, S.frame.height);
    setMaskIn(target, mask, target.session.layer);
    $("last-click").textContent = `mask in ${Math.round(answer.elapsed_ms)} ms · SAM2 IoU ${score(answer.score)}`;
    if (target === S.edit) changed();
  })();
  track(run);
}

/** Count `run` as pending (saving waits for it; the page shows "segmenting…"), toast its error. */
export function track(run, onError = () => {}) {
  S.inflight.add(run);
  $("busy").hidden = false;
  exposeState();
  run.catch((error) => { toast(error.message, "error"); onError(); }).finally(() => {
    S.inflight.delete(run);
    $("busy").hidden = S.inflight.size === 0;
    exposeState();
  });
}

// --- the outline as polygons (tool 7): drag, add and remove vertices -------------------------
//
// The mask shown is traced once into polygons (outer boundaries and holes, by the server with
// OpenCV); an edit makes a new state whose outline is the edited polygons, and the server fills
// them back into the mask. Undo and redo restore mask and outline together.

/** Show the outline of the current mask while the polygon tool is on (tracing it if needed). */
export function showOutline() {
  const outline = S.edit?.outline;
  const mask = S.edit ? maskOf(S.edit) : null;
  const editing = S.tool === "polygon" && !S.validation && kindOf() !== "points";
  // Current: traced from this mask, or being traced or filled from it (pending).
  const current = outline && outline.layer === S.layer && (outline.mask === mask || (outline.mask === null && outline.base === mask));
  S.stage.polygons = editing && current ? outline.polygons : null;
  if (!editing || S.stage.newPolygon?.layer !== S.layer) S.stage.newPolygon = null;
  if (editing && !current && S.edit) traceOutline(S.edit);
  if (S.stage.selectedVertex && !S.stage.polygons?.[S.stage.selectedVertex.polygon]?.points[S.stage.selectedVertex.index]) {
    S.stage.selectedVertex = null;
  }
}

export function traceOutline(target) {
  const layer = S.layer;
  const mask = maskOf(target, layer);
  target.outline = { mask: null, base: mask, polygons: [], layer }; // pending: traced once
  const run = (async () => {
    const answer = mask.any()
      ? await api(`/frames/${FRAME_ID}/outline`, { method: "POST", json: { mask_png: await pngOf(mask), tolerance: outlineTolerance() } })
      : { polygons: [] };
    target.outline = { mask, polygons: answer.polygons, layer };
    if (target === S.edit) { showOutline(); exposeState(); S.stage.requestRender(); }
  })();
  track(run, () => { target.outline = null; });
}

/** A new state whose outline is `change`d (a deep copy); its mask follows from the server. */
export function editOutline(change) {
  const polygons = S.edit.outline.polygons.map((p) => ({ hole: p.hole, points: p.points.map((q) => [...q]) }));
  change(polygons);
  const edited = withMask(S.edit, maskOf(S.edit)); // the pool's: its keypoints follow the mask
  commit({ ...edited, outline: { mask: null, base: maskOf(S.edit), polygons, layer: S.layer }, session: null });
  return S.edit;
}

export function fillOutline(target) {
  const run = (async () => {
    const answer = await api(`/frames/${FRAME_ID}/outline/mask`, { method: "POST", json: { polygons: target.outline.polygons } });
    const mask = await Mask.fromPng(answer.mask_png, S.frame.width, S.frame.height);
    const { layer, polygons } = target.outline;
    setMaskIn(target, mask, layer);
    target.outline = { mask, polygons, layer };
    if (target === S.edit) changed();
  })();
  track(run, () => { if (target === S.edit) undo(); });
}

/** Remove a vertex; a polygon left with fewer than 3 goes (an outer one with its holes). */
export function removeVertex({ polygon, index }) {
  const target = editOutline((polygons) => {
    polygons[polygon].points.splice(index, 1);
    if (polygons[polygon].points.length >= 3) return;
    let end = polygon + 1;
    if (!polygons[polygon].hole) while (end < polygons.length && polygons[end].hole) end++;
    polygons.splice(polygon, end - polygon);
  });
  S.stage.selectedVertex = null;
  fillOutline(target);
}

// --- a new polygon, corner by corner (tool 7 away from the outline) --------------------------

/** A corner of the new polygon at frame pixel (x, y); a click on its first corner closes it. */
export function addCorner(x, y, sx, sy) {
  if (S.stage.onFirstCorner(sx, sy)) { closePolygon(); return; }
  const points = S.stage.newPolygon?.points ?? [];
  S.stage.newPolygon = { layer: S.layer, points: [...points, clampToFrame([x, y])] };
  S.stage.requestRender();
}

/** Close the new polygon (3 corners or more): it joins the edited layer's outline, filled by
 *  the server as the outline's edits are. Returns whether there was one to close. */
export function closePolygon() {
  const points = S.stage.newPolygon?.points;
  if (!points || points.length < 3) return false;
  if (!S.stage.polygons || !S.edit.outline?.mask) {
    toast("The outline is still being traced; close the polygon again in a moment.", "info");
    return true;
  }
  S.stage.newPolygon = null;
  fillOutline(editOutline((polygons) => polygons.push({ hole: false, points })));
  showOutline();
  S.stage.requestRender();
  return true;
}

// --- pointer gestures on the canvas ---------------------------------------------------------

export function local(event) {
  const rect = S.stage.canvas.getBoundingClientRect();
  return [event.clientX - rect.left, event.clientY - rect.top];
}

export function clampToFrame([x, y]) {
  return [Math.min(S.frame.width, Math.max(0, x)), Math.min(S.frame.height, Math.max(0, y))];
}

export function onPointerDown(event) {
  const [sx, sy] = local(event);
  S.stage.canvas.focus();
  S.stage.canvas.setPointerCapture(event.pointerId);
  const [x, y] = S.stage.toImage(sx, sy);
  const inside = x >= 0 && y >= 0 && x <= S.frame.width && y <= S.frame.height;
  S.gesture = { kind: "pan", sx, sy, lastX: sx, lastY: sy, moved: 0 };
  if (event.button === 1 || S.spaceHeld) return;
  if (S.ruler.active) { // the ruler takes the clicks while it is out; elsewhere a drag pans
    if (event.button === 0) S.gesture = S.ruler.pointerDown(sx, sy, x, y, inside) ?? S.gesture;
    return;
  }
  if (kindOf() === "points" && !S.validation) {
    if (!S.ruler.active) S.gesture = pointsDown(event, sx, sy, x, y, inside) ?? S.gesture;
    return;
  }
  if (S.tool === "keypoint") {
    const index = S.stage.keypointAt(sx, sy);
    const key = S.validation ? "manual" : "keypoints";
    if (event.button === 2) {
      S.gesture = null;
      if (index >= 0) deleteKeypoint(index);
      return;
    }
    if (index < 0) {
      if (!inside) return;
      if (S.validation && S.edit.manual.length >= K) {
        toast(`All ${K} keypoints are placed; drag one to move it, or remove one first.`, "info");
        S.gesture = null;
        return;
      }
      const added = withPoint(S.edit[key], [x, y], orderCentre(S.edit[key]));
      commit({ ...S.edit, [key]: added.points, kpEdited: S.edit.kpEdited || !S.validation });
      S.stage.selected = added.index;
    } else {
      S.stage.selected = index;
    }
    // Selecting an existing keypoint is no edit; moving it is (committed on the first move).
    S.gesture = { kind: "keypoint", key, index: S.stage.selected, committed: index < 0 };
    changed();
    return;
  }
  if (S.tool === "polygon") {
    const corner = { kind: "corner", sx, sy, lastX: sx, lastY: sy, moved: 0, x, y };
    // Drawing a new polygon, or before the outline is traced: a click is a corner.
    if (S.stage.newPolygon || !S.stage.polygons || !S.edit.outline?.mask) {
      if (event.button === 0 && inside) S.gesture = corner;
      return;
    }
    const vertex = S.stage.vertexAt(sx, sy);
    if (vertex && event.button === 2) { S.gesture = null; removeVertex(vertex); return; }
    if (vertex && event.button === 0) {
      S.stage.selectedVertex = vertex;
      S.gesture = { kind: "vertex", ...vertex, committed: false };
      S.stage.requestRender();
      return;
    }
    const edge = event.button === 0 ? S.stage.edgeAt(sx, sy) : null;
    if (edge) { // a new vertex on the edge, dragged from here
      editOutline((polygons) => polygons[edge.polygon].points.splice(edge.index, 0, [edge.x, edge.y]));
      S.stage.selectedVertex = { polygon: edge.polygon, index: edge.index };
      S.gesture = { kind: "vertex", polygon: edge.polygon, index: edge.index, committed: true };
      showOutline();
      S.stage.requestRender();
      return;
    }
    if (event.button === 0 && inside) S.gesture = corner; // elsewhere: a new polygon's first corner (a drag pans)
    return;
  }
  if (!inside && S.tool !== "box") return;
  if (S.tool === "brush" || S.tool === "eraser") {
    if (event.button !== 0) return;
    commit({ ...withMask(S.edit, maskOf(S.edit).clone()), session: null });
    const rect = maskOf(S.edit).stamp(x, y, brushRadius(), S.tool === "brush" ? 1 : 0);
    activeOverlay().paint(maskOf(S.edit), rect);
    S.gesture = { kind: "brush", x, y, value: S.tool === "brush" ? 1 : 0 };
    S.stage.requestRender();
  } else if (S.tool === "box") {
    if (event.button !== 0) return;
    const [cx, cy] = clampToFrame([x, y]);
    S.gesture = { kind: "box", x: cx, y: cy };
    S.stage.draft = [cx, cy, cx, cy];
  } else {
    const positive = (S.tool === "positive") !== (event.shiftKey || event.button === 2);
    S.gesture = { kind: "click", sx, sy, lastX: sx, lastY: sy, moved: 0, x, y, positive };
  }
}

export function onPointerMove(event) {
  const [sx, sy] = local(event);
  const [x, y] = S.stage.toImage(sx, sy);
  if (S.tool === "brush" || S.tool === "eraser") {
    S.stage.cursor = { x, y, radius: brushRadius(), erase: S.tool === "eraser" };
    S.stage.requestRender();
  }
  if (!S.gesture) {
    S.stage.canvas.classList.toggle("over-keypoint", S.tool === "keypoint" && S.stage.keypointAt(sx, sy) >= 0);
    S.stage.canvas.classList.toggle("over-vertex", S.tool === "polygon" && S.stage.vertexAt(sx, sy) !== null);
    S.stage.canvas.classList.toggle("over-edge", S.tool === "polygon" && !S.stage.vertexAt(sx, sy) && S.stage.edgeAt(sx, sy) !== null);
    return;
  }
  if (S.gesture.kind === "click" || S.gesture.kind === "corner") {
    S.gesture.moved = Math.max(S.gesture.moved, Math.hypot(sx - S.gesture.sx, sy - S.gesture.sy));
    if (S.gesture.moved > 4) S.gesture.kind = "pan";
  }
  if (S.gesture.kind === "pan") {
    S.stage.panBy(sx - S.gesture.lastX, sy - S.gesture.lastY);
    S.gesture.lastX = sx;
    S.gesture.lastY = sy;
  } else if (S.gesture.kind === "brush") {
    const rect = maskOf(S.edit).line(S.gesture.x, S.gesture.y, x, y, brushRadius(), S.gesture.value);
    activeOverlay().paint(maskOf(S.edit), rect);
    S.gesture.x = x;
    S.gesture.y = y;
    S.stage.requestRender();
  } else if (S.gesture.kind === "box") {
    const [cx, cy] = clampToFrame([x, y]);
    S.stage.draft = [Math.min(S.gesture.x, cx), Math.min(S.gesture.y, cy), Math.max(S.gesture.x, cx), Math.max(S.gesture.y, cy)];
    S.stage.requestRender();
  } else if (S.gesture.kind === "vertex") {
    if (!S.gesture.committed) {
      S.gesture.committed = true;
      editOutline(() => {});
      showOutline();
    }
    S.edit.outline.polygons[S.gesture.polygon].points[S.gesture.index] = clampToFrame([x, y]);
    S.stage.requestRender();
  } else if (S.gesture.kind === "ruler") {
    S.ruler.move(S.gesture.index, x, y);
  } else if (S.gesture.kind === "named") {
    pointsMove(S.gesture, clampToFrame([x, y]));
  } else if (S.gesture.kind === "keypoint") {
    if (!S.gesture.committed) {
      S.gesture.committed = true;
      commit({ ...S.edit, [S.gesture.key]: copyPoints(S.edit[S.gesture.key]), kpEdited: S.edit.kpEdited || !S.validation });
    }
    S.edit[S.gesture.key][S.gesture.index] = clampToFrame([x, y]);
    S.stage.requestRender();
  }
}

export function onPointerUp() {
  const done = S.gesture;
  S.gesture = null;
  if (!done) return;
  if (done.kind === "click") {
    addClick(done.x, done.y, done.positive);
  } else if (done.kind === "corner") {
    addCorner(done.x, done.y, done.sx, done.sy);
  } else if (done.kind === "box") {
    const box = S.stage.draft;
    S.stage.draft = null;
    if (box && box[2] - box[0] >= 2 && box[3] - box[1] >= 2) setBox(box);
    else S.stage.requestRender();
  } else if (done.kind === "vertex") {
    if (done.committed) fillOutline(S.edit);
  } else if (done.kind === "brush" || done.kind === "keypoint" || done.kind === "named") {
    changed();
  }
}

/** Each tool button enabled when usable; SAM2's say why they are not. */
export function enableTools() {
  for (const button of document.querySelectorAll("#tools .tool")) {
    button.disabled = !toolUsable(button.dataset.tool);
    if (SAM2_PROBLEM && SAM2_TOOLS.has(button.dataset.tool)) button.title = SAM2_PROBLEM;
  }
}
