// Small DOM helpers shared by the pages: element builder, toasts, formatting.

/** `h("a", {href: "/"}, "text", child)`: an element with attributes and children. */
export function h(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs ?? {})) {
    if (value === undefined || value === null || value === false) continue;
    if (key.startsWith("on") && typeof value === "function") node.addEventListener(key.slice(2), value);
    else if (key === "dataset") Object.assign(node.dataset, value);
    else if (key === "text") node.textContent = value;
    else if (key === "style") node.style.cssText = value; // CSSOM: allowed by the CSP, an attribute is not
    else node.setAttribute(key, value === true ? "" : value);
  }
  for (const child of children.flat()) {
    if (child === undefined || child === null || child === false) continue;
    node.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return node;
}

/** A message in the corner: kind is "info", "ok" or "error". */
export function toast(message, kind = "info", ms = 4000) {
  const box = document.getElementById("toasts");
  if (!box) return;
  const item = h("div", { class: `toast ${kind}`, role: kind === "error" ? "alert" : "status", "data-testid": `toast-${kind}` }, message);
  box.append(item);
  setTimeout(() => item.remove(), kind === "error" ? ms * 2 : ms);
}

export function formatDate(text) {
  if (!text) return "";
  const date = new Date(text.endsWith("Z") || text.includes("+") ? text : `${text}Z`);
  return date.toLocaleString(undefined, { dateStyle: "short", timeStyle: "medium" });
}

export function formatBytes(bytes) {
  if (bytes < 1024) return `${bytes} B`;
  if (bytes < 1024 ** 2) return `${(bytes / 1024).toFixed(0)} KiB`;
  return `${(bytes / 1024 ** 2).toFixed(1)} MiB`;
}

/** A status pill. */
export function badge(text, extra = "") {
  return h("span", { class: `badge ${text} ${extra}`.trim() }, text);
}

/** A thin progress bar with a fraction 0..1. */
export function progressBar(fraction, label = "") {
  const bar = h("div", { class: "progress", role: "progressbar", "aria-valuemin": "0", "aria-valuemax": "100", "aria-valuenow": String(Math.round(fraction * 100)), title: label });
  bar.append(h("div", { class: "fill", style: `width:${(fraction * 100).toFixed(1)}%` }));
  return bar;
}

export function setProgress(bar, fraction) {
  bar.setAttribute("aria-valuenow", String(Math.round(fraction * 100)));
  bar.firstElementChild.style.width = `${(fraction * 100).toFixed(1)}%`;
}

/** Where a label stands in the review stage, in words. */
export const REVIEW_WORDS = { awaiting: "awaiting review", returned: "sent back", approved: "approved" };

/** A pill for a label's review state (awaiting · sent back · approved). */
export function reviewBadge(state) {
  return h("span", { class: `badge review-${state}`, "data-testid": "review-badge" }, REVIEW_WORDS[state] ?? state);
}
