// Picking a class (its button or its hotkey): its object on the frame becomes the edited layer,
// made when the frame has none; the tools follow the layer's kind.

import { toast } from "../ui.js";
import { CONFIG, POOL, addObject, classOf, objectsOf, selectLayer } from "./layers.js";
import { PAGE_KEYS } from "./page.js";
import { S } from "./state.js";
import { setTool } from "./tools.js";

/** The class whose hotkey is `key` (lower case), unless the page's own shortcuts take it. */
export function classForKey(key) {
  if (PAGE_KEYS.has(key)) return null;
  return CONFIG.classes.find((spec) => spec.hotkey?.toLowerCase() === key) ?? null;
}

/** Edit class `name`: the pool, or the last of its objects on the frame (a new one if none). */
export function pickClass(name, { fresh = false } = {}) {
  if (S.validation) { toast("Leave the validation mode (V) to edit the other classes.", "info"); return; }
  if (name === POOL) selectLayer(POOL);
  else {
    const objects = objectsOf(name);
    if (objects.length && !fresh) selectLayer(objects.at(-1).uid);
    else addObject(name);
  }
  afterPick();
}

/** Edit the layer `uid` (a row of the layer list). */
export function pickLayer(uid) {
  if (S.validation) return;
  selectLayer(uid);
  afterPick();
}

/** The pool's keypoint tool means nothing on another class's mask: the brush instead. */
function afterPick() {
  const spec = S.layer === POOL ? null : classOf(S.edit.objects.find((o) => o.uid === S.layer)?.cls);
  if (spec && spec.kind !== "points" && S.tool === "keypoint") setTool("brush");
  S.stage.canvas.focus();
}
