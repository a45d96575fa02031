// The users page (admins): the lab's users with role, state and last login; add one, change a
// role, deactivate or reactivate, set a new password. Each refusal is the server's sentence.

import { api } from "./api.js";
import { peopleSection } from "./people.js";
import { badge, formatDate, h, toast } from "./ui.js";

const rows = document.getElementById("user-rows");
const dialog = document.getElementById("password-dialog");
const ROLES = ["annotator", "reviewer", "admin"];
const ME = document.querySelector("[data-testid=current-user]")?.textContent.trim() ?? "";
let target = null;

async function change(user, patch, done) {
  try {
    await api(`/users/${user.id}`, { method: "PATCH", json: patch });
    toast(done, "ok");
  } catch (error) {
    toast(error.message, "error");
  }
  await load();
}

function roleSelect(user) {
  const select = h("select", { class: "role-select", "data-testid": "user-role", "aria-label": `Role of ${user.username}` },
    ...ROLES.map((role) => h("option", { value: role, selected: role === user.role }, role)));
  select.addEventListener("change", () => change(user, { role: select.value }, `${user.username} is now ${select.value}.`));
  return select;
}

function activity(user) {
  if (user.is_active) {
    return h("button", {
      type: "button", class: "danger", "data-testid": "deactivate-user",
      onclick: () => {
        const self = user.username === ME ? " You will be logged out." : "";
        if (confirm(`Deactivate ${user.username}? They are logged out at once and cannot log in until reactivated.${self}`)) {
          change(user, { is_active: false }, `${user.username} is deactivated.`);
        }
      },
    }, "Deactivate");
  }
  return h("button", { type: "button", class: "secondary", "data-testid": "reactivate-user", onclick: () => change(user, { is_active: true }, `${user.username} is active again.`) }, "Reactivate");
}

function row(user) {
  return h("tr", { "data-testid": "user-row", "data-username": user.username, class: user.is_active ? "" : "inactive" },
    h("td", {}, user.username, user.username === ME ? h("span", { class: "muted" }, " (you)") : ""),
    h("td", {}, roleSelect(user)),
    h("td", {}, badge(user.is_active ? "active" : "deactivated")),
    h("td", { "data-testid": "last-login" }, user.last_login_at ? formatDate(user.last_login_at) : h("span", { class: "muted" }, "never")),
    h("td", {}, formatDate(user.created_at)),
    h("td", { class: "actions" },
      h("button", { type: "button", class: "secondary", "data-testid": "set-password", onclick: () => askPassword(user) }, "Set password"), " ",
      activity(user)));
}

function askPassword(user) {
  target = user;
  document.getElementById("password-for").textContent = user.username;
  dialog.querySelector("form").reset();
  dialog.showModal();
}

document.getElementById("password-cancel").addEventListener("click", () => dialog.close());
document.getElementById("set-password-form").addEventListener("submit", (event) => {
  const password = event.target.elements.password.value;
  if (target && password) change(target, { password }, `${target.username} has a new password and is logged out everywhere.`);
});

async function load() {
  try {
    const users = await api("/users");
    rows.replaceChildren(...users.map(row));
  } catch (error) {
    toast(error.message, "error");
  }
  document.body.dataset.ready = "1";
}

document.getElementById("new-user").addEventListener("submit", async (event) => {
  event.preventDefault();
  const form = event.target.elements;
  const body = { username: form.username.value.trim(), role: form.role.value, password: form.password.value };
  try {
    await api("/users", { method: "POST", json: body });
    toast(`${body.username} added as ${body.role}.`, "ok");
    event.target.reset();
  } catch (error) {
    toast(error.message, "error");
  }
  load();
});

load();
peopleSection(document.getElementById("people"));
