// Undo and redo between immutable editing states (each step says the state changed), what is
// unsaved, and what the canvas shows as data attributes.

import { HISTORY_LIMIT } from "./page.js";
import { S, changed } from "./state.js";

// --- state and history ----------------------------------------------------------------------

export function commit(next) {
  S.past.push(S.edit);
  if (S.past.length > HISTORY_LIMIT) S.past.shift();
  S.future.length = 0;
  S.edit = next;
  changed();
}

export function undo() {
  if (!S.past.length) return;
  S.future.push(S.edit);
  S.edit = S.past.pop();
  followLayer(S.future.at(-1), S.edit);
  changed("edit", "layers");
}

export function redo() {
  if (!S.future.length) return;
  S.past.push(S.edit);
  S.edit = S.future.pop();
  followLayer(S.past.at(-1), S.edit);
  changed("edit", "layers");
}

/** After undo or redo from `before` to `after`: the layer that step changed is the one edited
 *  (the pool's mask or keypoints, else the object replaced); a layer gone leaves the pool. */
function followLayer(before, after) {
  if (before.mask !== after.mask || before.keypoints !== after.keypoints) S.layer = "pool";
  else {
    const stepped = after.objects.find((o) => !before.objects.includes(o));
    if (stepped) S.layer = stepped.uid;
  }
  if (S.layer !== "pool" && !after.objects.some((o) => o.uid === S.layer)) S.layer = "pool";
}

/** Whether the other classes' objects or the frame's tags and attributes changed. */
export const othersDirty = () => S.edit && (S.edit.objects !== S.labelClean.objects
  || S.edit.tags !== S.labelClean.tags || S.edit.attributes !== S.labelClean.attributes);
export const labelDirty = () => S.edit && (S.edit.mask !== S.labelClean.mask || S.edit.keypoints !== S.labelClean.keypoints || othersDirty());
export const manualDirty = () => S.edit && S.edit.manual !== S.manualClean;

export function sameKeypoints(a, b) {
  return a.length === b.length && a.every(([x, y], i) => Math.abs(x - b[i][0]) < 1e-6 && Math.abs(y - b[i][1]) < 1e-6);
}

/** Whether the shown label is the newest proposal, untouched (Accept then stores "accepted"). */
export function isProposal() {
  return S.proposal !== null && S.edit.mask.equals(S.proposal.mask) && sameKeypoints(S.edit.keypoints, S.proposal.keypoints);
}

/** What the canvas shows, as data attributes: for people inspecting the page and for tests. */
export function exposeState() {
  const data = S.stage.canvas.dataset;
  data.maskArea = String(S.edit.mask.area());
  data.keypoints = JSON.stringify(S.edit.keypoints.map(([x, y]) => [Math.round(x * 10) / 10, Math.round(y * 10) / 10]));
  data.manual = JSON.stringify(S.edit.manual.map(([x, y]) => [Math.round(x * 10) / 10, Math.round(y * 10) / 10]));
  data.clicks = String(S.edit.session?.points.length ?? 0);
  data.revision = String(S.revision);
  data.pending = String(S.inflight.size);
  data.outline = JSON.stringify(S.stage.polygons ?? []);
}
