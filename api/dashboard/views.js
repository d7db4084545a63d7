// @ts-check
/* The page's views: each fills its part of index.html from the API's answers and nothing else. */

import { $, breakable, clear, el } from "./dom.js";
import {
  diff, digitClass, digitMeaning, fmtBudget, fmtDelta, fmtGain, fmtLoss, fmtRunning, fmtSeconds, fmtSlots, fmtStatus, fmtTime,
  isOperator, neuralNames,
} from "./format.js";

/** @typedef {import("./types.js").Job} Job */
/** @typedef {import("./types.js").Round} Round */
/** @typedef {import("./types.js").History} History */
/** @typedef {import("./types.js").Cluster} Cluster */
/** @typedef {import("./types.js").Holder} Holder */

/** @param {Job} job */
function badge(job) {
  return el("span", { class: "badge s-" + String(job.status).toLowerCase(), text: fmtStatus(job.status, job.reason) });
}

/** The hash that opens a job. @param {string} id */
const jobHref = (id) => "#job=" + encodeURIComponent(id);

/** @param {Job} job */
function miniProgress(job) {
  const p = job.progress;
  if (p && p.total > 0) {
    const pct = Math.round((100 * p.done) / p.total);
    return el("div", { class: "mini" },
      el("div", { class: "mini-bar" }, el("div", { class: "mini-fill", style: `width:${pct}%` })),
      el("span", { class: "muted", text: `round ${p.round} · ${p.done}/${p.total}` }));
  }
  if (job.status === "QUEUED") return el("span", { class: "muted", text: "waiting" });
  if (job.status === "PREPARING") return el("span", { class: "muted", text: "preparing data" });
  /** @type {Record<string, string>} */
  const ends = { CONVERGED: "converged", STOPPED: "finished", CANCELLED: "cancelled", FAILED: "failed" };
  const end = job.reason === "budget" ? "budget spent" : job.reason === "stop_when" ? "good enough" : ends[job.status];
  return el("span", { class: "muted", text: end || "–" });
}

/** The jobs table; a click on a row selects its job through the URL hash.
 * @param {Job[]} jobs @param {string | null} selected */
export function renderJobs(jobs, selected) {
  $("auth").hidden = true;
  $("jobs-panel").hidden = false;
  const table = /** @type {HTMLTableElement} */ ($("jobs"));
  const body = clear(table.tBodies[0]);
  for (const job of jobs) {
    const href = jobHref(job.id);
    const tr = el("tr", { "data-job": job.id, class: job.id === selected ? "selected" : null },
      el("td", {}, el("a", { href, title: job.id, text: job.name || job.id.slice(0, 8) }),
        job.name ? el("span", { class: "muted id", text: " " + job.id.slice(0, 8) }) : null),
      el("td", { text: job.model }),
      el("td", {}, badge(job)),
      el("td", { class: "num", text: job.last_round === null ? "0" : String(job.last_round + 1) }),
      el("td", { class: "mono", text: job.current_state || "–" }),
      el("td", {}, miniProgress(job)),
      el("td", { class: "muted", text: fmtTime(job.created_at) }));
    tr.addEventListener("click", (ev) => {
      if (ev.target instanceof Element && ev.target.closest("a")) return;
      location.hash = href;
    });
    body.appendChild(tr);
  }
  $("jobs-empty").hidden = jobs.length > 0;
  table.hidden = jobs.length === 0;
  $("jobs-count").textContent = jobs.length ? `${jobs.length} job${jobs.length > 1 ? "s" : ""}, newest first` : "";
}

/** The "Running now" panel: a card per running job, side by side, with its live progress and what
 * its candidates in flight hold of the cluster; hidden while nothing runs. A click opens the job.
 * @param {Job[]} running the running jobs this caller may see, in display order
 * @param {Cluster | null} cluster null when it could not be read @param {string | null} selected */
export function renderRunning(running, cluster, selected) {
  const count = cluster ? cluster.running_jobs.length : running.length;
  $("running-panel").hidden = count === 0;
  $("running-count").textContent = fmtRunning(count, cluster ? cluster.max_running_jobs : null);
  const holders = new Map((cluster ? cluster.holders : []).map((h) => [h.job_id, h]));
  const box = clear($("running"));
  for (const job of running) box.appendChild(runCard(job, holders.get(job.id), job.id === selected));
}

/** One running job's card. @param {Job} job @param {Holder | undefined} holder @param {boolean} selected */
function runCard(job, holder, selected) {
  const p = job.progress;
  const href = jobHref(job.id);
  const counting = Boolean(p && p.total > 0);
  const pct = p && counting ? (100 * p.done) / p.total : 0;
  const doing = p && counting ? `round ${p.round} · ${p.done}/${p.total} candidates`
    : p && p.message ? p.message : job.status === "RUNNING" ? "starting a round" : "preparing data";
  const spent = fmtBudget((job.spec || {}).budget, job.used_wall_s, job.used_cpu_s);
  const card = el("article", { class: "run-card" + (selected ? " selected" : ""), "data-job": job.id },
    el("div", { class: "run-head" },
      el("a", { href, title: job.id, class: "run-name", text: job.name || job.id.slice(0, 8) }),
      job.status !== "RUNNING" ? badge(job) : null),
    el("div", { class: "muted run-sub", text: `${job.model} · ${job.id.slice(0, 8)}` }),
    el("div", { class: "run-progress", text: doing }),
    el("div", { class: "mini-bar run-bar" + (counting ? "" : " waiting") }, el("div", { class: "mini-fill", style: `width:${pct.toFixed(1)}%` })),
    el("div", { class: "run-facts" },
      el("span", { class: "run-best", text: "best " + fmtLoss(p ? p.best_val_loss : null) }),
      el("span", { class: "run-slots muted", text: fmtSlots(holder) })),
    spent.length ? el("div", { class: "run-budget muted", text: spent.join(" · ") }) : null);
  card.addEventListener("click", (ev) => {
    if (ev.target instanceof Element && ev.target.closest("a")) return;
    location.hash = href;
  });
  return card;
}

/** The selected job's title, facts, status, buttons and summary cards.
 * @param {Job} job @param {Round[]} rounds @param {History | null} history @param {string[]} positions @param {boolean} cancelArmed */
export function renderHeader(job, rounds, history, positions, cancelArmed) {
  $("job-title").textContent = job.name || "job " + job.id.slice(0, 8);
  const spec = job.spec || {};
  const search = spec.search || {};
  const bits = [job.id, job.model, `created ${fmtTime(job.created_at)}`];
  if (search.radius !== undefined) bits.push(`radius ${search.radius}`);
  if (search.epochs_per_round !== undefined) bits.push(`${search.epochs_per_round} epochs/round`);
  if (search.max_rounds !== undefined) bits.push(`max ${search.max_rounds} rounds`);
  if (Array.isArray(spec.data)) bits.push(spec.data.map((/** @type {{source: string}} */ d) => d.source).join(" + "));
  if (job.priority) bits.push(`priority ${job.priority}`);
  bits.push(...fmtBudget(spec.budget, job.used_wall_s, job.used_cpu_s));
  $("job-meta").textContent = bits.join(" · ");
  const status = $("job-status");
  status.textContent = fmtStatus(job.status, job.reason);
  status.className = "badge s-" + job.status.toLowerCase();

  const err = $("job-error");
  err.textContent = job.error ? "Error: " + job.error : "";
  err.hidden = !job.error;

  const cancel = $("cancel");
  cancel.hidden = job.terminal;
  cancel.textContent = cancelArmed ? "Really cancel?" : "Cancel job";

  const download = /** @type {HTMLButtonElement} */ ($("download"));
  download.disabled = job.last_round === null;
  download.title = job.last_round === null ? "available once round 0 is committed" : "";

  const last = rounds[rounds.length - 1];
  $("card-rounds").textContent = String(rounds.length);
  $("card-loss").textContent = last ? fmtLoss(last.winner_val_loss) : "–";
  const gain = history ? history.gain_over_start : null;
  $("card-gain").textContent = fmtGain(gain);
  $("card-gain").title = history && history.start_val_loss !== null
    ? `the starting ${job.model} state trained the same epochs in round 0: ${fmtLoss(history.start_val_loss)}` : "";
  const state = job.current_state || (last && last.winner_state);
  $("card-neural").textContent = state ? `${neuralNames(state, positions).length} of ${positions.length}` : "–";
}

/** The running round's progress bar; hidden for a finished job.
 * @param {Job} job */
export function renderProgress(job) {
  const box = $("progress");
  const p = job.progress;
  if (job.terminal || (!p && job.status !== "QUEUED" && job.status !== "PREPARING")) {
    box.hidden = true;
    return;
  }
  box.hidden = false;
  let label, detail = "", pct = 0;
  if (!p || p.total === 0) {
    label = job.status === "QUEUED" ? "Queued: waiting for the worker" : (p && p.message ? `Round ${p.round}: ${p.message}` : "Preparing the data");
  } else {
    pct = (100 * p.done) / p.total;
    label = `Round ${p.round}: ${p.done} of ${p.total} candidates trained`;
    const parts = [];
    if (p.best_val_loss !== null) parts.push(`best so far ${fmtLoss(p.best_val_loss)}${p.state ? " (" + p.state + ")" : ""}`);
    if (p.message) parts.push(p.message);
    parts.push(`elapsed ${fmtSeconds(p.elapsed_s)}`);
    detail = parts.join(" · ");
  }
  $("progress-label").textContent = label;
  $("progress-detail").textContent = detail;
  $("progress-fill").style.width = pct.toFixed(1) + "%";
  box.classList.toggle("indeterminate", !p || p.total === 0);
}

/** A position's choices by digit, as the job serves them (none for older services).
 * @param {Job | null | undefined} job @param {string} position @returns {string[] | undefined} */
function choicesAt(job, position) {
  return job && job.choices ? job.choices[position] : undefined;
}

/** What a round's change column says: the served change, or why it stayed.
 * @param {Round} r */
function changeText(r) {
  if (r.kind === "polish") return "polish: trained on, lr decaying";
  const stop = r.extra && r.extra.stop_when ? ` · stopped: ${r.extra.stop_when}` : "";
  if (r.change !== "stay") return r.change + stop;
  return r.converged ? "stay: converged" : "stay";
}

/** The trail through the hypercube: one row per round, a digit per position.
 * @param {Round[]} rounds @param {string[]} positions @param {Job | null} job */
export function renderTrail(rounds, positions, job) {
  const table = /** @type {HTMLTableElement} */ ($("trail"));
  const head = clear(/** @type {HTMLTableSectionElement} */ (table.tHead));
  const body = clear(table.tBodies[0]);
  const foot = clear(/** @type {HTMLTableSectionElement} */ (table.tFoot));
  const nodes = positions.filter((n) => !isOperator(n)).length;
  // Candidates scored on held-out materials (search.score, neuenh.selection): the winner's fit score beside its val loss.
  const fit = rounds.some((r) => r.winner_fit_score !== null && r.winner_fit_score !== undefined);
  const byFit = !!(job && job.spec && job.spec.search && job.spec.search.score === "fit");
  const tail = fit ? 4 : 3;
  if (positions.length) {
    head.appendChild(el("tr", { class: "groups" },
      el("th", { colspan: 1 }),
      nodes ? el("th", { colspan: nodes, class: "group", text: "terms" }) : null,
      positions.length - nodes ? el("th", { colspan: positions.length - nodes, class: "group ops", text: "operators" }) : null,
      el("th", { colspan: tail })));
    head.appendChild(el("tr", {},
      el("th", { class: "num", text: "Round" }),
      positions.map((name, i) => el("th", { class: "pos" + (isOperator(name) ? " op" : ""), "data-index": i, title: name }, breakable(name))),
      el("th", { text: "Change that won" }),
      el("th", { class: "num", text: "Winner val loss" + (fit && !byFit ? " (selects)" : "") }),
      fit ? el("th", { class: "num", title: "held-out log-L1 on the materials the data holds out, fitted with the winner's modules frozen",
        text: "Winner fit score" + (byFit ? " (selects)" : "") }) : null,
      el("th", { class: "num", text: "Wall" })));
  }
  /** @type {number | null} */
  let prevLoss = null;
  for (const r of rounds) {
    const changed = new Set(diff(r.parent_state, r.winner_state));
    const cells = [];
    for (let i = 0; i < positions.length; i++) {
      const d = r.winner_state[i] || "?";
      cells.push(el("td", {
        class: `digit ${digitClass(d)}` + (changed.has(i) ? " flipped" : ""),
        title: `${positions[i]}: ${digitMeaning(d, choicesAt(job, positions[i]))}` + (changed.has(i) ? ` (was ${r.parent_state[i]})` : ""),
        text: d,
      }));
    }
    const delta = fmtDelta(prevLoss, r.winner_val_loss);
    prevLoss = r.winner_val_loss;
    body.appendChild(el("tr", { "data-round": r.round, "data-state": r.winner_state },
      el("td", { class: "num", text: String(r.round) }),
      cells,
      el("td", { class: "change" + (changed.size ? "" : " stay") }, changeText(r)),
      el("td", { class: "num mono" }, fmtLoss(r.winner_val_loss),
        delta ? el("span", { class: "delta " + (delta.down ? "down" : "up"), text: delta.text }) : null),
      fit ? el("td", { class: "num mono fit-score", text: fmtLoss(r.winner_fit_score ?? null) }) : null,
      el("td", { class: "num muted" }, fmtSeconds(r.wall_s),
        r.recovered > 0 ? el("span", { class: "recovered", title: "candidates that had finished before a service restart, read back instead of trained again", text: `${r.recovered} recovered` }) : null)));
  }
  const p = job && !job.terminal ? job.progress : null;
  if (p && p.total > 0 && !rounds.some((r) => r.round === p.round)) {
    foot.appendChild(el("tr", { class: "pending" },
      el("td", { class: "num", text: String(p.round) }),
      el("td", { colspan: positions.length + tail, text: `training… ${p.done}/${p.total} candidates` + (p.best_val_loss !== null ? `, best ${fmtLoss(p.best_val_loss)}` : "") })));
  }
  $("trail-empty").hidden = rounds.length > 0 || !job;
  table.hidden = positions.length === 0;
}

/** The final (or current) model: its state digit by digit with the position names.
 * @param {Job} job @param {string | null} state @param {Round[]} rounds @param {string[]} positions */
export function renderFinal(job, state, rounds, positions) {
  $("final-heading").textContent = job.terminal ? "Final model" : "Current model (last committed round)";
  const strip = clear($("final-state"));
  const text = $("final-text");
  if (!state) {
    text.textContent = !job.terminal ? "No model yet: it is available once round 0 is committed."
      : job.reason === "budget" ? "No model: its budget ran out before round 0 was committed." : "No model: no round was committed.";
    return;
  }
  strip.appendChild(el("span", { class: "mono state-code", text: state }));
  for (let i = 0; i < positions.length; i++) {
    const d = state[i] || "?";
    const names = choicesAt(job, positions[i]);
    const named = d !== "0" && d !== "1" && names && names[parseInt(d, 36)];
    strip.appendChild(el("span", { class: `chip ${digitClass(d)}`, title: digitMeaning(d, names) },
      el("span", { class: "chip-name", text: named ? `${positions[i]} ${named}` : positions[i] }),
      el("span", { class: "chip-digit", text: d })));
  }
  const neural = neuralNames(state, positions);
  const last = rounds[rounds.length - 1];
  const parts = [neural.length ? `neural at ${neural.join(", ")}` : "all terms analytical"];
  if (last) parts.push(`validation loss ${fmtLoss(last.winner_val_loss)} after round ${last.round}`);
  if (job.status === "CONVERGED") parts.push("converged: no single change improved it further");
  else if (job.status === "STOPPED") {
    parts.push(job.reason === "budget" ? "stopped: its budget ran out"
      : job.reason === "stop_when" ? "stopped: good enough for its cost (search.stop_when)" : "stopped at max_rounds");
  }
  text.textContent = parts.join(" · ");
}
