// A points class's layer: its named points placed by a click (the next name the class lists,
// or the next number when it lists none), moved by a drag, removed by a right-click or Delete.

import { toast } from "../ui.js";
import { commit } from "./history.js";
import { activeObject, classOf, withObject } from "./layers.js";
import { S, changed } from "./state.js";

const HIT = 12; // screen pixels around a point that pick it

/** The name the next click places on `object`, or null when its class's names are all placed. */
export function nextName(object) {
  const names = classOf(object.cls)?.point_names;
  if (names?.length) return names.find((name) => !(name in object.points)) ?? null;
  let n = 1;
  while (String(n) in object.points) n++;
  return String(n);
}

/** The name of the edited object's point under the screen point (sx, sy), or null. */
export function pointAt(sx, sy) {
  let best = null;
  for (const [name, [x, y]] of Object.entries(activeObject()?.points ?? {})) {
    const [px, py] = S.stage.toScreen(x, y);
    const d = Math.hypot(px - sx, py - sy);
    if (d <= HIT && (!best || d < best.d)) best = { name, d };
  }
  return best?.name ?? null;
}

/** The edited object without its point `name` (one undo step). */
export function removePoint(name) {
  const object = activeObject();
  if (!object || !(name in object.points)) return;
  const points = { ...object.points };
  delete points[name];
  commit(withObject(S.edit, { ...object, points }));
  S.selectedPoint = null;
  changed();
}

/** A pointer press on a points layer: the gesture it starts, or null (pan). */
export function pointsDown(event, sx, sy, x, y, inside) {
  const object = activeObject();
  const hit = pointAt(sx, sy);
  if (event.button === 2) {
    if (hit) removePoint(hit);
    return { kind: "none" };
  }
  if (event.button !== 0) return null;
  if (hit) {
    S.selectedPoint = hit;
    changed("layers");
    return { kind: "named", name: hit, committed: false };
  }
  if (!inside) return null;
  const name = nextName(object);
  if (name === null) {
    toast(`Every point of ${object.cls} is placed; drag one to move it, or remove one first.`, "info");
    return { kind: "none" };
  }
  commit(withObject(S.edit, { ...object, points: { ...object.points, [name]: [x, y] } }));
  S.selectedPoint = name;
  return { kind: "named", name, committed: true };
}

/** A drag of the point `gesture.name` to `xy` (frame pixels; the first move is the undo step). */
export function pointsMove(gesture, xy) {
  const object = activeObject();
  if (!object) return;
  if (!gesture.committed) {
    gesture.committed = true;
    commit(withObject(S.edit, { ...object, points: { ...object.points, [gesture.name]: xy } }));
  } else {
    object.points[gesture.name] = xy; // the state this drag committed: its own copy
  }
  changed("layers");
}
