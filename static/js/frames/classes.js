// The list's filters on what labels hold: a class present, a frame tag, a frame attribute's
// value, offered from the label configuration (the server checks them and says what it knows).

import { api } from "../api.js";
import { h } from "../ui.js";
import { filterForm } from "./state.js";

/** The values a frame attribute's filter can take, as `name:value` (text and numbers: the name). */
function attributeValues(spec) {
  if (spec.type === "choice") return spec.options.map((option) => `${spec.name}:${option}`);
  if (spec.type === "flag") return [`${spec.name}:true`, `${spec.name}:false`];
  return [`${spec.name}:`];
}

/** Fill the class and tag selects and the attribute's suggestions from the configuration. */
export async function loadClassFilters() {
  const config = await api("/label-config");
  const classes = document.getElementById("filter-class");
  classes.replaceChildren(h("option", { value: "" }, "any"),
    ...config.classes.map((c) => h("option", { value: c.name }, c.name === "pool" ? "pool (a pool mask)" : `${c.name} (${c.kind})`)));
  const tags = config.frame_tags ?? [];
  document.getElementById("filter-tag").replaceChildren(h("option", { value: "" }, "any"), ...tags.map((t) => h("option", { value: t }, t)));
  document.getElementById("filter-tag-field").hidden = !tags.length;
  const attributes = config.frame_attributes ?? [];
  document.getElementById("filter-attr-values").replaceChildren(
    ...attributes.flatMap(attributeValues).map((value) => h("option", { value })));
  document.getElementById("filter-attr-field").hidden = !attributes.length;
}

// Enter in the attribute field applies it (the form's change), never a page load.
filterForm.addEventListener("submit", (event) => {
  event.preventDefault();
  filterForm.dispatchEvent(new Event("change"));
});
