// Keypoints: their numbers in the order rule, adding and removing one (the list is drawn by
// panel.js, the validation mode is validation.js).

import { commit } from "./history.js";
import { K } from "./page.js";
import { S, changed } from "./state.js";

// --- numbers: the keypoints' fixed order ----------------------------------------------------
//
// A keypoint's number is its place in the order rule (weldpool_core.keypoints: clockwise on
// screen from the left of the pool's centre). A keypoint added by a click takes the number of
// its position among the others; deleting one leaves the others' numbers as they are (1, 3, 4
// until the second is placed again). A list of points from elsewhere (a proposal, the server)
// is numbered 1…n in its own order, which the server writes in the order rule.

const NUMBERS = new WeakMap();
const START = Math.PI; // the order rule's start direction: left on screen

/** The numbers shown for `points` (1…n unless an edit here gave them others). */
export const numbersOf = (points) => NUMBERS.get(points) ?? points.map((_, i) => i + 1);

function numbered(points, numbers) {
  NUMBERS.set(points, numbers);
  return points;
}

/** A copy of `points` (for an edit) that keeps their numbers. */
export const copyPoints = (points) => numbered(points.map((p) => [...p]), [...numbersOf(points)]);

const angle = ([x, y], [cx, cy]) => {
  const a = Math.atan2(y - cy, x - cx) - START;
  return ((a % (2 * Math.PI)) + 2 * Math.PI) % (2 * Math.PI);
};

/** `points` with `point` added where the order rule puts it around `centre`: the free number
 *  between its neighbours' (else every point renumbered by the rule); sorted by number. Returns
 *  the new list and the new point's index in it. */
export function withPoint(points, point, centre) {
  const numbers = numbersOf(points);
  const around = [...points.map((p, i) => ({ p, n: numbers[i] })), { p: point, n: null }]
    .sort((a, b) => angle(a.p, centre) - angle(b.p, centre));
  const at = around.findIndex((entry) => entry.n === null);
  const before = around.slice(0, at).map((e) => e.n);
  const after = around.slice(at + 1).map((e) => e.n);
  const low = before.length ? Math.max(...before) : 0;
  const high = after.length ? Math.min(...after) : Infinity;
  const used = new Set(numbers);
  let free = null;
  for (let n = low + 1; n < high && n <= Math.max(K, points.length + 1); n++) if (!used.has(n)) { free = n; break; }
  if (free === null) around.forEach((entry, i) => { entry.n = i + 1; }); // no room: the rule's order
  else around[at].n = free;
  const sorted = around.sort((a, b) => a.n - b.n);
  const result = numbered(sorted.map((e) => [...e.p]), sorted.map((e) => e.n));
  return { points: result, index: sorted.findIndex((e) => e.p === point) };
}

/** `points` without the one at `index`; the others keep their numbers. */
export function withoutPoint(points, index) {
  return numbered(points.filter((_, i) => i !== index), numbersOf(points).filter((_, i) => i !== index));
}

/** Where the order rule measures angles from: the mask's centre, else the keypoints', else
 *  the frame's. */
export function orderCentre(points) {
  const centre = S.edit.mask?.centroid?.();
  if (centre) return centre;
  if (points.length) return [points.reduce((s, p) => s + p[0], 0) / points.length, points.reduce((s, p) => s + p[1], 0) / points.length];
  return [S.frame.width / 2, S.frame.height / 2];
}

// --- removing one ---------------------------------------------------------------------------

export function deleteKeypoint(index) {
  if (S.validation) {
    commit({ ...S.edit, manual: withoutPoint(S.edit.manual, index) });
  } else {
    commit({ ...S.edit, keypoints: withoutPoint(S.edit.keypoints, index), kpEdited: true });
  }
  S.stage.selected = -1;
  changed();
}
