// The header's work badge on every page: what was sent back to me, what is handed to me still
// to review, and (reviewers) what awaits approval — each count opens its list.

import { REVIEW_STAGE, api, isReviewer } from "./api.js";
import { h } from "./ui.js";

const box = document.getElementById("work");

/** Each count, the words it shows and the list it opens (the frames page's filters). */
const ITEMS = [
  { key: "sent_back", words: "sent back", href: "/?assignee=me&review=returned&status=all&order=id", title: "Labels a reviewer sent back to you, with what to change", show: (n) => REVIEW_STAGE && (!isReviewer() || n > 0) },
  { key: "assigned", words: "assigned", href: "/?assignee=work&order=uncertainty", title: "Frames for you to label: handed to you, or given to several annotators with yours still due", show: () => true },
  { key: "awaiting_review", words: "to approve", href: "/?review=awaiting&status=all&order=id", title: "Annotators' labels awaiting a reviewer's approval", show: () => REVIEW_STAGE && isReviewer() },
];

/** Fetch the counts again and show them (pages call it after a save or a decision). */
export async function refreshWork() {
  if (!box) return;
  let work;
  try {
    work = await api("/users/me/work");
  } catch {
    return; // the badge is a convenience: a failed fetch leaves the last counts
  }
  const links = ITEMS.filter((item) => item.show(work[item.key])).map((item) => {
    const count = work[item.key];
    return h("a", { href: item.href, title: item.title, class: count ? "due" : "none", "data-testid": `work-${item.key.replaceAll("_", "-")}` },
      item.words, " ", h("b", {}, String(count)));
  });
  box.replaceChildren(...links);
  box.hidden = links.length === 0;
  box.dataset.ready = "1";
}

if (box) {
  refreshWork();
  setInterval(refreshWork, 60_000);
  document.addEventListener("visibilitychange", () => { if (!document.hidden) refreshWork(); });
}
