// The label's layers: the pool (the label's own mask and keypoints) and the objects of the
// other configured classes (`/label-config`), which of them is edited, how each is shown, and
// how they travel to and from the server. An object lives in the editing state (`S.edit.objects`:
// {uid, cls, mask | points, attributes, retired?}) and is replaced, never changed, by an edit, so one
// history undoes any layer. A retired object (its class removed from the configuration with
// force) is shown read-only; the server keeps it until a save names it in `remove_retired`.

import { commit } from "./history.js";
import { Mask, ObjectOverlay } from "./mask.js";
import { S, changed } from "./state.js";

export const POOL = "pool";
/** Colours for classes the configuration gives none (the pool keeps its own). */
const PALETTE = ["#e64980", "#40c057", "#fab005", "#7950f2", "#15aabf", "#fd7e14", "#82c91e", "#be4bdb"];

/** The configuration in force: {classes: [{name, kind, color, hotkey, attributes, point_names}],
 *  frame_tags, frame_attributes}; the pool alone until it is loaded. */
export const CONFIG = { classes: [{ name: POOL, kind: "mask", attributes: [] }], frame_tags: [], frame_attributes: [] };

export function setConfig(config) {
  const classes = (config?.classes ?? []).map((spec, i) => ({ attributes: [], ...spec, color: spec.color ?? PALETTE[i % PALETTE.length] }));
  if (!classes.some((spec) => spec.name === POOL)) classes.unshift({ name: POOL, kind: "mask", attributes: [] });
  Object.assign(CONFIG, { classes, frame_tags: config?.frame_tags ?? [], frame_attributes: config?.frame_attributes ?? [] });
}

/** The colour a class is drawn in: its own, the pool's as the page always drew it. */
export const colourOf = (spec) => (spec?.name === POOL ? "#00c8ff" : spec?.color ?? PALETTE[0]);
export const classOf = (name) => CONFIG.classes.find((spec) => spec.name === name) ?? null;
/** What an object of the label is drawn as: its class, or, retired, a grey one of its shape. */
export const specOf = (object) => (object.retired
  ? { name: object.cls, kind: object.points ? "points" : "instances", color: RETIRED_COLOUR, attributes: [], retired: true }
  : classOf(object.cls));
export const RETIRED_COLOUR = "#868e96";
export const kindOf = (layer = S.layer) => (layer === POOL ? "mask" : specOf(objectOf(S.edit, layer) ?? {})?.kind ?? "mask");
export const objectOf = (edit, uid = S.layer) => (uid === POOL ? null : edit.objects.find((o) => o.uid === uid) ?? null);
export const activeObject = () => objectOf(S.edit);

let counter = 0;
export const newUid = () => `o${++counter}`;

// --- the active layer's mask --------------------------------------------------------------------

/** The mask of `layer` in the editing state `edit` (the pool's, or an object's). */
export function maskOf(edit, layer = S.layer) {
  return layer === POOL ? edit.mask : objectOf(edit, layer)?.mask ?? null;
}

/** A new editing state whose `layer` has `mask` (the pool's counts as an edit of its mask). */
export function withMask(edit, mask, layer = S.layer) {
  if (layer === POOL) return { ...edit, mask, maskEdited: true };
  return { ...edit, objects: edit.objects.map((o) => (o.uid === layer ? { ...o, mask } : o)) };
}

/** Put `mask` into `layer` of the pending state `target` (an answer that arrives later). */
export function setMaskIn(target, mask, layer) {
  Object.assign(target, withMask(target, mask, layer));
}

/** A new editing state with `object` in place of the one with its uid. */
export const withObject = (edit, object) => ({ ...edit, objects: edit.objects.map((o) => (o.uid === object.uid ? object : o)) });

// --- objects: added, removed, picked ------------------------------------------------------------

/** Make `uid` the edited layer (the pool, or an object on the frame). */
export function selectLayer(uid) {
  if (objectOf(S.edit, uid)?.retired) return; // read-only: shown, hidden or removed, never edited
  S.layer = uid === POOL || objectOf(S.edit, uid) ? uid : POOL;
  S.selectedPoint = null;
  changed("edit", "layers");
}

/** A new, empty object of class `name`, edited from now on (one undo step). */
export function addObject(name) {
  const spec = classOf(name);
  const object = { uid: newUid(), cls: name, attributes: {} };
  if (spec.kind === "points") object.points = {};
  else object.mask = new Mask(S.frame.width, S.frame.height);
  commit({ ...S.edit, objects: [...S.edit.objects, object] });
  selectLayer(object.uid);
  return object;
}

/** An object taken off the label; a retired one is also remembered in the editing state's
 *  `removed` (the uids its × took off), so undo puts it back and a label loaded or taken in
 *  place of this one names none of them. */
export function removeObject(uid) {
  const retired = objectOf(S.edit, uid)?.retired;
  const removed = retired ? [...(S.edit.removed ?? []), uid] : S.edit.removed;
  commit({ ...S.edit, objects: S.edit.objects.filter((o) => o.uid !== uid), removed });
  if (S.layer === uid) selectLayer(POOL);
  LOOK.delete(uid);
}

/** The editable objects of class `name`, in order (an instance's number is its place here). */
export const objectsOf = (name) => S.edit.objects.filter((o) => o.cls === name && !o.retired);

export function objectName(object) {
  if (object.retired) {
    const same = S.edit.objects.filter((o) => o.retired && o.cls === object.cls);
    return same.length > 1 ? `${object.cls} ${same.indexOf(object) + 1}` : object.cls;
  }
  const spec = classOf(object.cls);
  if (spec?.kind !== "instances") return object.cls;
  return `${object.cls} ${objectsOf(object.cls).indexOf(object) + 1}`;
}

// --- how each layer is shown (this page only, not history) --------------------------------------

/** uid → {visible, opacity}; the pool's are the page's Mask checkbox and mask opacity. */
export const LOOK = new Map();
export const lookOf = (uid) => LOOK.get(uid) ?? { visible: true, opacity: 1 };
export function setLook(uid, change) {
  LOOK.set(uid, { ...lookOf(uid), ...change });
}

const OVERLAYS = new Map(); // uid → ObjectOverlay in its class's colour

/** The overlay of an object's mask (as big as its box), painted from it when the mask is new. */
export function overlayOf(object) {
  let overlay = OVERLAYS.get(object.uid);
  if (!overlay) {
    overlay = new ObjectOverlay(colourOf(specOf(object)));
    OVERLAYS.set(object.uid, overlay);
  }
  if (overlay.mask !== object.mask) overlay.paint(object.mask);
  return overlay;
}

/** Bytes the objects' masks and overlays hold now (what bench/review_layers_memory.py reads). */
export const heldBytes = () => S.edit.objects.filter((o) => o.mask).reduce((sum, o) => sum + o.mask.data.byteLength + overlayOf(o).bytes, 0);

// --- to and from the server ---------------------------------------------------------------------

/** The label's objects as the editing state holds them, its retired ones (`label.retired`)
 *  read-only, each with its `position` in the label (what `retiredOf` remembers). Pure: a label
 *  only looked at (a conflict's, an annotator's) leaves `S.retired` as it is. */
export function objectsFromLabel(label, width, height) {
  const objects = [];
  const retired = new Set(label?.retired?.objects ?? []);
  for (const [position, item] of (label?.objects ?? []).entries()) {
    const spec = retired.has(position) ? null : classOf(item.class);
    if (!retired.has(position) && (!spec || spec.name === POOL)) continue;
    const object = { uid: newUid(), cls: item.class, attributes: { ...(item.attributes ?? {}) } };
    // Of a class given the other shape since (an annotator's own label lists no `retired`).
    const misfit = spec !== null && (spec.kind === "points") !== Boolean(item.points);
    if (spec === null || misfit) object.retired = true;
    if (item.points) object.points = Object.fromEntries(Object.entries(item.points).map(([k, p]) => [k, [...p]]));
    else if (item.rle) object.mask = Mask.fromRle(item.rle.counts, width, height);
    else continue;
    if (object.retired) object.position = position;
    objects.push(object);
  }
  return objects;
}

/** Where the server lists the retired parts of the label being edited (`objects` from
 *  `objectsFromLabel(label)`), to name them in `remove_retired` when the reviewer removes one;
 *  `retiredOf(null, [])` for a label whose retired parts are not the frame label's. */
export const retiredOf = (label, objects) => ({
  objects: new Map(objects.filter((o) => o.retired).map((o) => [o.uid, o.position])),
  tags: label?.retired?.tags ?? [],
  attributes: label?.retired?.attributes ?? [],
});

/** After a save: where the server now lists the retired parts still shown (in their order);
 *  where its list is not theirs one for one (a conflict overwritten, their retired parts kept
 *  beside mine) none is named for removal any more: kept rather than the wrong one removed. */
export function adoptRetired(label) {
  const shown = S.edit.objects.filter((o) => o.retired && S.retired.objects.has(o.uid)).map((o) => o.uid);
  const positions = label.retired?.objects ?? [];
  const paired = shown.length === positions.length ? shown.map((uid, k) => [uid, positions[k]]) : [];
  S.retired = { objects: new Map(paired), tags: label.retired?.tags ?? [], attributes: label.retired?.attributes ?? [] };
  S.edit = { ...S.edit, removed: [] }; // named in the save just made
  S.labelClean = S.edit;
}

/** The retired parts the reviewer removed here (none: null): what `remove_retired` names — the
 *  objects whose × this editing state holds, where the label they were read from is the one
 *  edited (their positions are its). */
function removedRetired() {
  const removed = {
    objects: (S.edit.removed ?? []).filter((uid) => S.retired.objects.has(uid)).map((uid) => S.retired.objects.get(uid)),
    tags: S.retired.tags.filter((tag) => !S.edit.tags.includes(tag)),
    attributes: S.retired.attributes.filter((name) => !(name in S.edit.attributes)),
  };
  return removed.objects.length || removed.tags.length || removed.attributes.length ? removed : null;
}

/** The editing state's other classes of a label (or an annotator's own): objects, tags, attributes. */
export const othersFromLabel = (label, width, height) => ({
  objects: objectsFromLabel(label, width, height),
  tags: [...(label?.tags ?? [])],
  attributes: { ...(label?.attributes ?? {}) },
});

const isEmpty = (object) => (object.points ? !Object.keys(object.points).length : !object.mask.any());

/** What a save sends beside the pool: `objects`, `tags`, `attributes`, each only when changed
 *  here (left out, the label keeps what it holds), or every one of them with `all` (mine kept
 *  whole over a label saved meanwhile, an annotator's own label), and the retired parts removed
 *  here. Empty objects are not sent, nor retired ones (the server keeps those unless named). */
export async function othersBody({ all = false } = {}) {
  const body = {};
  const removed = all ? null : removedRetired(); // mine over theirs: their positions differ
  if (removed) body.remove_retired = removed;
  if (all || S.edit.objects !== S.labelClean.objects) {
    body.objects = await Promise.all(S.edit.objects.filter((o) => !o.retired && !isEmpty(o)).map(async (o) => {
      const item = { class: o.cls };
      if (o.points) item.points = o.points;
      else item.mask_png = await o.mask.toPng();
      if (Object.keys(o.attributes).length) item.attributes = o.attributes;
      return item;
    }));
  }
  if (all || S.edit.tags !== S.labelClean.tags) body.tags = S.edit.tags;
  if (all || S.edit.attributes !== S.labelClean.attributes) body.attributes = S.edit.attributes;
  return body;
}
