// The label configuration page (admins): the classes beside the built-in pool, their kind,
// colour, hotkey, attributes and a points class's point names, and the frame's tags and
// attributes; a save is a new version (a stale one, or one removing a class labels hold, is the
// server's sentence).

import { api } from "./api.js";
import { h, toast } from "./ui.js";

const rows = document.getElementById("class-rows");
const form = document.getElementById("config-form");
const KINDS = ["mask", "instances", "points"];
const PALETTE = ["#1f77b4", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22"];
let version = 0;

/** "size:choice:small|large, hot:flag" → attribute specs (the server checks them). */
export function parseAttributes(text) {
  return text.split(",").map((part) => part.trim()).filter(Boolean).map((part) => {
    const [name, type = "text", options] = part.split(":").map((v) => v.trim());
    const spec = { name, type };
    if (options) spec.options = options.split("|").map((v) => v.trim()).filter(Boolean);
    return spec;
  });
}

export function formatAttributes(specs = []) {
  return specs.map((a) => [a.name, a.type, ...(a.options ? [a.options.join("|")] : [])].join(":")).join(", ");
}

/** A colour no row has yet (the palette's first free one). */
function nextColor() {
  const used = new Set([...rows.querySelectorAll("[name=color]")].map((input) => input.value));
  return PALETTE.find((c) => !used.has(c)) ?? PALETTE[rows.children.length % PALETTE.length];
}

function classRow(spec) {
  const builtin = spec.name === "pool";
  const kind = h("select", { name: "kind", "data-testid": "class-kind", disabled: builtin, "aria-label": "Kind" },
    ...KINDS.map((k) => h("option", { value: k, selected: k === spec.kind }, k)));
  // A points class's named points (the wire tip's "tip"), kept as the config has them.
  const points = h("input", { name: "point_names", value: (spec.point_names ?? []).join(", "), maxlength: 2000, size: 10, placeholder: "e.g. tip", disabled: spec.kind !== "points", "data-testid": "class-points", "aria-label": "Point names" });
  kind.addEventListener("change", () => { points.disabled = kind.value !== "points"; });
  const row = h("tr", { "data-testid": "class-row", "data-builtin": builtin ? "1" : "" },
    h("td", {}, h("input", { name: "name", value: spec.name, required: true, maxlength: 64, readonly: builtin, "data-testid": "class-name", "aria-label": "Name" })),
    h("td", {}, kind),
    h("td", {}, h("input", { type: "color", name: "color", value: spec.color ?? nextColor(), "data-testid": "class-color", "aria-label": "Colour" })),
    h("td", {}, h("input", { name: "hotkey", value: spec.hotkey ?? "", maxlength: 1, size: 2, "data-testid": "class-hotkey", "aria-label": "Hotkey" })),
    h("td", {}, h("input", { name: "attributes", value: formatAttributes(spec.attributes), maxlength: 2000, "data-testid": "class-attributes", "aria-label": "Attributes" })),
    h("td", {}, points),
    h("td", { class: "actions" }, builtin ? h("span", { class: "muted" }, "built in")
      : h("button", { type: "button", class: "danger", "data-testid": "remove-class", onclick: () => row.remove() }, "Remove")));
  return row;
}

function read() {
  const classes = [...rows.querySelectorAll("tr[data-testid=class-row]")].map((row) => {
    const value = (name) => row.querySelector(`[name=${name}]`).value.trim();
    const spec = { name: value("name"), kind: value("kind"), color: value("color"), attributes: parseAttributes(value("attributes")) };
    if (value("hotkey")) spec.hotkey = value("hotkey");
    const names = value("point_names").split(",").map((n) => n.trim()).filter(Boolean);
    if (spec.kind === "points" && names.length) spec.point_names = names;
    return spec;
  });
  const tags = document.getElementById("frame-tags").value.split(",").map((t) => t.trim()).filter(Boolean);
  return { version, classes, frame_tags: tags, frame_attributes: parseAttributes(document.getElementById("frame-attributes").value) };
}

function show(config) {
  version = config.version;
  document.getElementById("config-version").textContent = config.version
    ? `Version ${config.version}${config.updated_by ? ` by ${config.updated_by}` : ""}` : "Not configured yet: the pool alone";
  rows.replaceChildren(...config.classes.map(classRow));
  document.getElementById("frame-tags").value = (config.frame_tags ?? []).join(", ");
  document.getElementById("frame-attributes").value = formatAttributes(config.frame_attributes);
}

async function save(body) {
  try {
    show(await api("/label-config", { method: "PUT", json: body }));
    toast(`Saved as version ${version}.`, "ok");
  } catch (error) {
    if (error.status === 409 && /force/.test(error.message) && confirm(`${error.message}\n\nSave anyway?`)) {
      return save({ ...body, force: true });
    }
    toast(error.message, "error", 8000);
  }
}

document.getElementById("add-class").addEventListener("click", () => {
  const row = classRow({ name: "", kind: "mask" });
  rows.append(row);
  row.querySelector("[name=name]").focus();
});
form.addEventListener("submit", (event) => {
  event.preventDefault();
  save(read());
});

api("/label-config").then((config) => {
  show(config);
  document.body.dataset.ready = "1";
}, (error) => toast(error.message, "error"));
