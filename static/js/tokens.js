// The API-token page: the caller's tokens (never the tokens themselves), create one (shown
// once), revoke one with confirmation.

import { api } from "./api.js";
import { badge, formatDate, h, toast } from "./ui.js";

const rows = document.getElementById("token-rows");

async function revoke(token) {
  if (!confirm(`Revoke the token “${token.name || token.prefix}”? Scripts that use it stop working at once.`)) return;
  try {
    await api(`/tokens/${token.id}`, { method: "DELETE" });
    toast(`Token “${token.name || token.prefix}” revoked.`, "ok");
  } catch (error) {
    toast(error.message, "error");
  }
  load();
}

function row(token) {
  const revoked = token.revoked_at !== null;
  return h("tr", { "data-testid": "token-row", "data-token-id": String(token.id) },
    h("td", {}, token.name || h("span", { class: "muted" }, "unnamed")),
    h("td", {}, h("code", {}, `${token.prefix}…`)),
    h("td", {}, formatDate(token.created_at)),
    h("td", {}, token.last_used_at ? formatDate(token.last_used_at) : h("span", { class: "muted" }, "never")),
    h("td", {}, badge(revoked ? "revoked" : "active")),
    h("td", {}, revoked ? "" : h("button", { type: "button", class: "danger", "data-testid": "revoke-token", onclick: () => revoke(token) }, "Revoke")));
}

async function load() {
  try {
    const tokens = await api("/tokens");
    rows.replaceChildren(...(tokens.length ? tokens.map(row)
      : [h("tr", {}, h("td", { colspan: "6", class: "muted" }, "No tokens yet."))]));
  } catch (error) {
    toast(error.message, "error");
  }
  document.body.dataset.ready = "1";
}

document.getElementById("new-token").addEventListener("submit", async (event) => {
  event.preventDefault();
  const name = event.target.elements.name.value.trim();
  try {
    const created = await api("/tokens", { method: "POST", json: { name } });
    document.getElementById("created-text").textContent = created.token;
    document.getElementById("created").hidden = false;
    event.target.reset();
  } catch (error) {
    toast(error.message, "error");
  }
  load();
});

document.getElementById("copy-token").addEventListener("click", async () => {
  try {
    await navigator.clipboard.writeText(document.getElementById("created-text").textContent);
    toast("Copied.", "ok");
  } catch {
    toast("Select the token and copy it by hand.", "info");
  }
});

load();
