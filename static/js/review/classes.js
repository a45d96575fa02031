// What the side panel and canvas show of the classes: the class picker (colour, hotkey), the
// layer list (visibility, opacity, the edited layer, instances added and removed), the edited
// object's attributes, the frame's tags and attributes; the other classes' masks and points on
// the canvas. The page's entry subscribes `renderClasses` to the state's changes.

import { h } from "../ui.js";
import { applyDisplay, setMaskVisible } from "./display.js";
import { commit } from "./history.js";
import { CONFIG, POOL, activeObject, classOf, colourOf, lookOf, objectName, overlayOf, removeObject, setLook, specOf, withObject } from "./layers.js";
import { $, PAGE_KEYS } from "./page.js";
import { pickClass, pickLayer } from "./picker.js";
import { S } from "./state.js";

/** Redraw what shows the classes when the editing state or the layers changed. */
export function renderClasses(parts) {
  if (!S.edit || !(parts.has("edit") || parts.has("layers"))) return;
  const configured = CONFIG.classes.length > 1 || CONFIG.frame_tags.length || CONFIG.frame_attributes.length;
  const retired = S.retired.tags.length || S.retired.attributes.length;
  $("classes-section").hidden = !configured && !S.edit.objects.length && !retired;
  renderPicker();
  renderLayerList();
  renderObjectAttributes();
  renderFrameFields();
  drawLayers();
}

const swatch = (colour) => {
  const node = h("span", { class: "class-swatch", "aria-hidden": "true" });
  node.style.background = colour;
  return node;
};

function renderPicker() {
  const active = S.layer === POOL ? POOL : activeObject()?.cls;
  $("class-picker").replaceChildren(...CONFIG.classes.map((spec) => {
    const taken = spec.hotkey && PAGE_KEYS.has(spec.hotkey.toLowerCase());
    const key = spec.hotkey ? h("kbd", { class: taken ? "taken" : "", title: taken ? "The page's own shortcut takes this key: pick the class with the mouse" : `Press ${spec.hotkey} to pick it` }, spec.hotkey) : "";
    const button = h("button", {
      type: "button", class: `class-option${spec.name === active ? " active" : ""}`, "aria-pressed": String(spec.name === active),
      "data-testid": "class-option", "data-class": spec.name, title: `${spec.name} (${spec.kind})`, onclick: () => pickClass(spec.name),
    }, swatch(colourOf(spec)), h("span", { class: "class-name" }, spec.name), key);
    if (spec.kind !== "instances") return button;
    return h("span", { class: "class-pair" }, button, h("button", {
      type: "button", class: "class-add", "data-testid": "add-instance", "data-class": spec.name,
      title: `Add another ${spec.name} object`, "aria-label": `Add a ${spec.name} object`, onclick: () => pickClass(spec.name, { fresh: true }),
    }, "+"));
  }));
}

const RETIRED_NOTE = "Its class was removed from the label configuration: shown read-only and kept on the label until you remove it (×) and save.";

function layerRow(uid, spec, name, detail, look, onLook) {
  const row = h("li", {
    class: `layer-row${uid === S.layer ? " active" : ""}${spec.retired ? " retired" : ""}`, "data-testid": "layer-row", "data-layer": uid, "data-class": spec.name,
    "data-retired": spec.retired ? "true" : null, title: spec.retired ? RETIRED_NOTE : null,
    "aria-current": uid === S.layer ? "true" : null, onclick: (event) => { if (!spec.retired && !event.target.closest("input, button")) pickLayer(uid); },
  },
  h("input", { type: "checkbox", checked: look.visible, "data-testid": "layer-visible", "aria-label": `Show ${name}`, onchange: (event) => onLook({ visible: event.target.checked }) }),
  swatch(colourOf(spec)), h("span", { class: "layer-name", title: name }, name, h("br"), h("span", { class: "muted small-text" }, detail)),
  h("input", { type: "range", min: 0, max: 1, step: 0.05, value: look.opacity, class: "layer-opacity", "data-testid": "layer-opacity", "aria-label": `Opacity of ${name}`, oninput: (event) => onLook({ opacity: Number(event.target.value) }) }));
  if (uid !== POOL) row.append(h("button", { type: "button", class: "quiet tiny-btn", "data-testid": "layer-remove", title: `Remove ${name}${spec.retired ? " from the label (its class was removed)" : ""}`, onclick: () => removeObject(uid) }, "×"));
  return row;
}

function renderLayerList() {
  const poolLook = { visible: S.stage.showMask, opacity: S.stage.display.maskOpacity };
  const poolRow = layerRow(POOL, classOf(POOL), POOL, `${S.edit.mask.area()} px`, poolLook, (change) => {
    if ("visible" in change) setMaskVisible(change.visible);
    if ("opacity" in change) applyDisplay({ ...S.stage.display, maskOpacity: change.opacity });
  });
  const rows = S.edit.objects.map((o) => {
    const spec = specOf(o);
    const names = spec.point_names;
    const size = o.points ? `${Object.keys(o.points).length}${names?.length ? ` of ${names.length}` : ""} points` : `${o.mask.area()} px`;
    const detail = o.retired ? "class removed" : size;
    return layerRow(o.uid, spec, objectName(o), detail, lookOf(o.uid), (change) => { setLook(o.uid, change); drawLayers(); });
  });
  $("layer-list").replaceChildren(poolRow, ...rows);
  const object = activeObject();
  $("layer-hint").textContent = object?.points
    ? `Click to place the next point of ${objectName(object)}; drag one to move it, right-click or Del removes it.`
    : `The tools edit ${object ? objectName(object) : "the pool"}.`;
}

// --- attributes: the edited object's and the frame's --------------------------------------------

/** An input for attribute `spec` showing `value`; `onValue` gets the new one (undefined: none). */
function attributeInput(spec, value, onValue, testid) {
  const common = { "data-testid": testid, "data-name": spec.name, "aria-label": spec.name };
  if (spec.type === "flag") {
    return h("input", { ...common, type: "checkbox", checked: value === true, onchange: (e) => onValue(e.target.checked) });
  }
  if (spec.type === "choice") {
    return h("select", { ...common, onchange: (e) => onValue(e.target.value || undefined) },
      h("option", { value: "" }, "—"), ...spec.options.map((o) => h("option", { value: o, selected: o === value }, o)));
  }
  const number = spec.type === "number";
  return h("input", {
    ...common, type: number ? "number" : "text", value: value ?? "", min: spec.min, max: spec.max, step: number ? "any" : null, maxlength: number ? null : 1000,
    onchange: (e) => onValue(e.target.value === "" ? undefined : number ? Number(e.target.value) : e.target.value),
  });
}

const withValue = (values, name, value) => {
  const next = { ...values };
  if (value === undefined) delete next[name];
  else next[name] = value;
  return next;
};

function attributeRows(specs, values, onChange, testid) {
  return specs.map((spec) => h("label", { class: spec.type === "flag" ? "check" : "attribute" },
    spec.type === "flag" ? "" : h("span", {}, spec.name),
    attributeInput(spec, values[spec.name], (value) => onChange(withValue(values, spec.name, value)), testid),
    spec.type === "flag" ? ` ${spec.name}` : ""));
}

function renderObjectAttributes() {
  const object = activeObject();
  const specs = object ? classOf(object.cls)?.attributes ?? [] : [];
  const box = $("object-attributes");
  box.hidden = !specs.length;
  if (box.hidden) return;
  box.replaceChildren(h("p", { class: "small-text attribute-head" }, `Attributes of ${objectName(object)}`),
    ...attributeRows(specs, object.attributes, (attributes) => commit(withObject(S.edit, { ...object, attributes })), "object-attribute"));
}

function renderFrameFields() {
  const box = $("frame-fields");
  const oldTags = S.edit.tags.filter((tag) => S.retired.tags.includes(tag));
  const configured = new Set(CONFIG.frame_attributes.map((spec) => spec.name));
  const oldAttributes = Object.entries(S.edit.attributes).filter(([name]) => !configured.has(name));
  box.hidden = !CONFIG.frame_tags.length && !CONFIG.frame_attributes.length && !oldTags.length && !oldAttributes.length;
  if (box.hidden) return;
  const chosen = new Set(S.edit.tags);
  $("frame-tags").replaceChildren(...CONFIG.frame_tags.map((tag) => h("button", {
    type: "button", class: `chip${chosen.has(tag) ? " on" : ""}`, "aria-pressed": String(chosen.has(tag)), "data-testid": "frame-tag", "data-tag": tag,
    onclick: () => commit({ ...S.edit, tags: chosen.has(tag) ? S.edit.tags.filter((t) => t !== tag) : [...S.edit.tags, tag] }),
  }, tag)), ...oldTags.map((tag) => h("span", { class: "chip retired", "data-testid": "retired-tag", "data-tag": tag, title: "This tag was removed from the label configuration: kept on the frame until you remove it (×) and save." },
    `${tag} · tag removed `, h("button", { type: "button", class: "quiet tiny-btn", "aria-label": `Remove the tag ${tag}`, onclick: () => commit({ ...S.edit, tags: S.edit.tags.filter((t) => t !== tag) }) }, "×"))));
  $("frame-attributes").replaceChildren(...attributeRows(CONFIG.frame_attributes, S.edit.attributes, (attributes) => commit({ ...S.edit, attributes }), "frame-attribute"),
    ...oldAttributes.map(([name, value]) => h("p", { class: "retired-field small-text", "data-testid": "retired-attribute", "data-name": name, title: "This attribute was removed from the label configuration: kept until you remove it (×) and save." },
      h("span", {}, `${name}: ${JSON.stringify(value)} · attribute removed `), h("button", { type: "button", class: "quiet tiny-btn", "aria-label": `Remove the attribute ${name}`, onclick: () => commit({ ...S.edit, attributes: withValue(S.edit.attributes, name, undefined) }) }, "×"))));
}

// --- the canvas ---------------------------------------------------------------------------------

/** The other classes' masks and points on the stage, and what they are as data attributes. */
export function drawLayers() {
  const stage = S.stage;
  stage.layers = S.edit.objects.filter((o) => o.mask && lookOf(o.uid).visible).map((o) => ({ overlay: overlayOf(o), alpha: lookOf(o.uid).opacity }));
  stage.namedPoints = S.edit.objects.filter((o) => o.points && lookOf(o.uid).visible).flatMap((o) => Object.entries(o.points).map(([name, [x, y]]) => ({
    x, y, name, colour: colourOf(specOf(o)), alpha: lookOf(o.uid).opacity, selected: o.uid === S.layer && name === S.selectedPoint,
  })));
  const active = activeObject(); // none while a label taken in place of mine is being set
  stage.canvas.dataset.layer = active ? objectName(active) : POOL;
  stage.canvas.dataset.objects = JSON.stringify(S.edit.objects.map((o) => ({
    name: objectName(o), class: o.cls, ...(o.retired ? { retired: true } : {}), ...(o.points ? { points: o.points } : { area: o.mask.area(), bbox: o.mask.bbox() }),
  })));
  stage.requestRender();
}
