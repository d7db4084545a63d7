// @ts-check
/* Scene plans (GET /v1/plans): the list, and for the plan named in the URL hash (#plan=<id>) its
 * progress while it runs (with a button to cancel it: a second click confirms), then every
 * material's chosen rung, the scene totals and the cost-against-error plot (fetched with the bearer
 * token and shown from a blob URL). */

import { getJSON, request } from "./api.js";
import { $, clear, el } from "./dom.js";
import { fmtStatus, fmtTime } from "./format.js";

/** @typedef {import("./types.js").Plan} Plan */

/** @param {Plan[]} plans @param {string | null} selected */
export function renderPlans(plans, selected) {
  const body = clear(/** @type {HTMLTableElement} */ ($("plans")).tBodies[0]);
  for (const p of plans) {
    const row = el("tr", { "data-plan": p.id, class: p.id === selected ? "selected" : "" },
      el("td", {}, el("a", { href: "#plan=" + p.id, text: p.name || p.id.slice(0, 8) })),
      el("td", {}, el("span", { class: "badge " + p.status.toLowerCase(), text: fmtStatus(p.status) })),
      el("td", { class: "num", text: `${p.materials_done}/${p.materials_total ?? "?"}` }),
      el("td", { class: "muted", text: fmtTime(p.created_at) }));
    row.addEventListener("click", () => { location.hash = "plan=" + p.id; });
    body.appendChild(row);
  }
  $("plans-empty").hidden = plans.length > 0;
  $("plans-count").textContent = plans.length ? `${plans.length} plan${plans.length === 1 ? "" : "s"}` : "";
}

/** @type {string | null} */
let plotUrl = null;

/** The selected plan: its header, its progress or its error, and when done its table and plot.
 * @param {Plan} p */
export async function renderPlan(p) {
  $("plan").hidden = false;
  $("plan-title").textContent = "plan " + (p.name || p.id);
  const meta = [fmtStatus(p.status), `${p.materials_done}/${p.materials_total ?? "?"} materials planned`];
  if (p.progress) meta.push(`${p.progress.step}/${p.progress.steps} fits: ${p.progress.message}`);
  if (p.error) meta.push(p.error);
  $("plan-meta").textContent = meta.join(" · ");
  const cancel = $("plan-cancel");
  cancel.hidden = p.terminal;
  cancel.textContent = armed === p.id ? "Really cancel?" : "Cancel plan";
  const body = clear(/** @type {HTMLTableElement} */ ($("plan-table")).tBodies[0]);
  const result = p.plan;
  $("plan-result").hidden = !result;
  if (!result) return;
  /** @type {Record<string, string>} */
  const labels = {};
  for (const r of result.ladder) labels[r.key] = r.label;
  for (const m of result.materials) {
    body.appendChild(el("tr", { "data-material": m.name },
      el("td", { text: m.name }),
      el("td", { class: "num", text: String(m.weight) }),
      el("td", { text: labels[m.chosen] || m.chosen }),
      el("td", { class: "num mono", text: m.error.toFixed(4) }),
      el("td", { class: "num mono", text: m.cost_ns.toFixed(0) }),
      el("td", { class: "num mono", text: m.richest.error.toFixed(4) })));
  }
  const t = result.totals;
  $("plan-totals").textContent = `frame cost ${t.plan.cost_ns.toFixed(0)} ns and error ${t.plan.error.toFixed(4)} `
    + `against ${t.richest.cost_ns.toFixed(0)} ns, ${t.richest.error.toFixed(4)} with the richest rung everywhere `
    + `and ${t.cheapest.cost_ns.toFixed(0)} ns, ${t.cheapest.error.toFixed(4)} with the cheapest everywhere`;
  const img = /** @type {HTMLImageElement} */ ($("plan-plot"));
  if (p.files["cost_vs_error.png"] && img.dataset.plan !== p.id) {
    const blob = await (await request(`/plans/${encodeURIComponent(p.id)}/files/cost_vs_error.png`)).blob();
    if (plotUrl) URL.revokeObjectURL(plotUrl);
    plotUrl = URL.createObjectURL(blob);
    img.src = plotUrl;
    img.dataset.plan = p.id;
  }
}

/** The plan a first click on "Cancel plan" armed (a second click within 4 s cancels it).
 * @type {string | null} */
let armed = null;

/** A click on "Cancel plan" of plan ``id``: the first arms it, the second cancels the plan; true
 * when the plan was cancelled (the caller then polls it). Errors propagate (the caller shows them).
 * @param {string} id @returns {Promise<boolean>} */
export async function cancelPlanClicked(id) {
  if (armed !== id) {
    armed = id;
    $("plan-cancel").textContent = "Really cancel?";
    setTimeout(() => {
      if (armed === id) { armed = null; $("plan-cancel").textContent = "Cancel plan"; }
    }, 4000);
    return false;
  }
  armed = null;
  await request(`/plans/${encodeURIComponent(id)}/cancel`, { method: "POST" });
  return true;
}

/** @returns {Promise<Plan[]>} */
export async function fetchPlans() {
  return (await getJSON("/plans")).plans;
}

/** @param {string} id @returns {Promise<Plan>} */
export async function fetchPlan(id) {
  return getJSON("/plans/" + encodeURIComponent(id));
}
