// @ts-check
/* neuenh dashboard: the jobs of this service, the running ones side by side with their live
 * progress and, for the job named in the URL hash (#job=<id>), its trail through the hypercube,
 * every candidate's validation loss, the running round's progress and the model download. Native
 * ES modules, no dependencies, no build step and no external URL: it works offline.
 *
 * Polling: the job list and the cluster (which jobs run now, what they hold) every LIST_MS, every
 * LIVE_MS while a job runs; the selected job (GET /v1/jobs/{id}) and its history
 * (GET .../history?since_round=k, appending the rounds it returns) every JOB_MS until the job is
 * terminal. A 401 shows the token form; the token is kept in localStorage and sent as a bearer
 * header, so the model download goes through fetch and a blob URL too.
 */

import { ApiError, getJSON, request, setToken, token } from "./api.js";
import { lossChart } from "./chart.js";
import { $, clear, el } from "./dom.js";
import { cancelPlanClicked, fetchPlan, fetchPlans, renderPlan, renderPlans } from "./plans.js";
import { renderFinal, renderHeader, renderJobs, renderProgress, renderRunning, renderTrail } from "./views.js";

/** @typedef {import("./types.js").Job} Job */
/** @typedef {import("./types.js").Round} Round */
/** @typedef {import("./types.js").History} History */
/** @typedef {import("./types.js").Cluster} Cluster */

const LIST_MS = 3000;
const LIVE_MS = 2000;
const JOB_MS = 2000;

/** What the page shows, replaced by each poll; the views only read it. */
class Page {
  /** @type {Job[]} */ jobs = [];
  /** @type {Job[]} */ running = [];              // the jobs running now (that this token may see), oldest first
  /** @type {Cluster | null} */ cluster = null;
  /** @type {string | null} */ selected = null;   // the job id from the hash
  /** @type {Job | null} */ job = null;
  /** @type {History | null} */ history = null;  // the last history answer (its start and gain)
  /** @type {Round[]} */ rounds = [];            // every round received, oldest first
  nextSince = 0;
  generation = 0;    // bumps when the selection changes: late answers for another job are dropped
  /** @type {ReturnType<typeof setTimeout> | undefined} */ listTimer = undefined;
  /** @type {ReturnType<typeof setTimeout> | undefined} */ jobTimer = undefined;
  needsToken = false;
  cancelArmed = false;

  /** @param {string | null} id */
  select(id) {
    this.selected = id;
    this.generation += 1;
    this.job = this.history = null;
    this.rounds = [];
    this.nextSince = 0;
    this.cancelArmed = false;
  }

  /** @param {History} history */
  addHistory(history) {
    this.history = history;
    const known = new Set(this.rounds.map((r) => r.round));
    for (const r of history.rounds) if (!known.has(r.round)) this.rounds.push(r);
    this.rounds.sort((a, b) => a.round - b.round);
    this.nextSince = Math.max(this.nextSince, history.next_since_round);
  }

  /** The job's position names; "#i" when the job is not known yet. */
  positions() {
    const job = this.job;
    if (job && job.positions && job.positions.length) return job.positions;
    const n = (job && job.current_state ? job.current_state.length : 0) || (this.rounds[0] ? this.rounds[0].winner_state.length : 0);
    return Array.from({ length: n }, (_, i) => "#" + i);
  }
}

const S = new Page();

/** @param {string} message */
function showError(message) {
  const box = $("error");
  box.textContent = message || "";
  box.hidden = !message;
}

/** @param {string} text @param {string} [cls] */
function setConn(text, cls) {
  const c = $("conn");
  c.textContent = text;
  c.className = "conn-state " + (cls || "");
}

/** @param {unknown} err */
function handleError(err) {
  if (err instanceof ApiError && err.status === 401) {
    askToken(err.message);
    return;
  }
  setConn("offline", "bad");
  showError(err instanceof Error ? err.message : String(err));
}

/** @param {string} message */
function askToken(message) {
  S.needsToken = true;
  stopTimers();
  $("auth").hidden = false;
  $("jobs-panel").hidden = true;
  $("running-panel").hidden = true;
  $("job").hidden = true;
  setConn("needs a token", "bad");
  const had = Boolean(token());
  const note = $("auth-error");
  note.textContent = had ? "The token was refused (" + message + "). Try again." : "";
  note.hidden = !had;
  $("token").focus();
}

function stopTimers() {
  clearTimeout(S.listTimer);
  clearTimeout(S.jobTimer);
  S.listTimer = S.jobTimer = undefined;
}

/** GET /cluster; null when it cannot be read (the running jobs then come from the list alone). */
async function getCluster() {
  try {
    return await getJSON("/cluster");
  } catch (err) {
    if (err instanceof ApiError && err.status === 401) throw err;
    return null;
  }
}

/** The running jobs, oldest first: those the cluster names, from the list or fetched when older
 * than its page (one this token may not see is left out); without the cluster, the list's
 * RUNNING and PREPARING jobs.
 * @param {Job[]} jobs @param {Cluster | null} cluster @returns {Promise<Job[]>} */
async function runningJobs(jobs, cluster) {
  const listed = new Map(jobs.map((j) => [j.id, j]));
  const found = cluster
    ? await Promise.all(cluster.running_jobs.map((id) => listed.get(id) || getJSON("/jobs/" + encodeURIComponent(id)).catch(() => null)))
    : jobs.filter((j) => j.status === "RUNNING" || j.status === "PREPARING");
  const running = /** @type {Job[]} */ (found.filter((j) => j && !j.terminal));
  return running.sort((a, b) => (a.created_at < b.created_at ? -1 : a.created_at > b.created_at ? 1 : 0));
}

async function pollList() {
  clearTimeout(S.listTimer);
  try {
    const [page, cluster, plans] = await Promise.all([getJSON("/jobs?limit=50"), getCluster(), fetchPlans()]);
    renderPlans(plans, planSelected());
    S.jobs = page.jobs;
    S.cluster = cluster;
    S.running = await runningJobs(page.jobs, cluster);
    showError("");
    setConn("live", "ok");
    renderJobs(S.jobs, S.selected);
    renderRunning(S.running, S.cluster, S.selected);
  } catch (err) {
    handleError(err);
  }
  if (!S.needsToken) S.listTimer = setTimeout(pollList, S.running.length ? LIVE_MS : LIST_MS);
}

/** The plan id in the hash (#plan=<id>), if any. */
function planSelected() {
  return new URLSearchParams(location.hash.replace(/^#/, "")).get("plan");
}

/** @type {ReturnType<typeof setTimeout> | undefined} */
let planTimer = undefined;

/** The plan named in the hash, polled until it ends (or is not found); a failed poll is tried again,
 * as a job's is, so a moment's error never leaves a stale status on the page. */
async function pollPlan() {
  clearTimeout(planTimer);
  const id = planSelected();
  $("plan").hidden = !id;
  if (!id || S.needsToken) return;
  let again = true;
  try {
    const plan = await fetchPlan(id);
    if (id !== planSelected()) return;
    await renderPlan(plan);
    again = !plan.terminal;
  } catch (err) {
    again = !(err instanceof ApiError && err.status === 404);
    handleError(err);
  }
  if (again && !S.needsToken && id === planSelected()) planTimer = setTimeout(pollPlan, JOB_MS);
}

/** @param {boolean} poll */
function selectFromHash(poll) {
  if (poll) pollPlan();
  const id = new URLSearchParams(location.hash.replace(/^#/, "")).get("job");
  if (id === S.selected) return;
  S.select(id);
  clearTimeout(S.jobTimer);
  $("download-note").hidden = true;
  $("job-error").hidden = true;
  for (const tr of /** @type {HTMLTableElement} */ ($("jobs")).tBodies[0].rows) tr.classList.toggle("selected", tr.dataset.job === id);
  for (const card of $("running").children) card.classList.toggle("selected", /** @type {HTMLElement} */ (card).dataset.job === id);
  if (!id) {
    $("job").hidden = true;
    return;
  }
  $("job").hidden = false;
  $("job-title").textContent = "job " + id;
  $("job-meta").textContent = "loading…";
  renderJob();
  if (poll && !S.needsToken) pollJob();
}

async function pollJob() {
  clearTimeout(S.jobTimer);
  const gen = S.generation;
  const id = S.selected;
  if (!id) return;
  let again = true;
  try {
    const path = "/jobs/" + encodeURIComponent(id);
    const [job, history] = await Promise.all([getJSON(path), getJSON(path + "/history?since_round=" + S.nextSince)]);
    if (gen !== S.generation) return;
    S.job = job;
    S.addHistory(history);
    // One more poll after the job turns terminal is not needed: this history answer was read
    // after the job record said terminal, so it holds every round.
    again = !(job.terminal && history.terminal);
    showError("");
    setConn("live", "ok");
    renderJob();
  } catch (err) {
    if (gen !== S.generation) return;
    if (err instanceof ApiError && err.status === 404) {
      again = false;
      $("job-title").textContent = "job " + id;
      $("job-meta").textContent = "";
      const box = $("job-error");
      box.textContent = "No such job: " + err.message;
      box.hidden = false;
    } else {
      handleError(err);
    }
  }
  if (again && !S.needsToken && gen === S.generation) S.jobTimer = setTimeout(pollJob, JOB_MS);
}

function renderJob() {
  const job = S.job, positions = S.positions();
  if (job) {
    renderHeader(job, S.rounds, S.history, positions, S.cancelArmed);
    renderProgress(job);
  }
  renderTrail(S.rounds, positions, job);
  clear($("chart")).appendChild(lossChart(S.rounds, Boolean(job)));
  if (job) {
    const last = S.rounds[S.rounds.length - 1];
    renderFinal(job, job.current_state || (last ? last.winner_state : null), S.rounds, positions);
  }
}

async function download() {
  const job = S.job;
  if (!job) return;
  const button = /** @type {HTMLButtonElement} */ ($("download"));
  const note = $("download-note");
  button.disabled = true;
  note.hidden = false;
  note.className = "note";
  note.textContent = "Preparing the model archive…";
  try {
    const response = await request("/jobs/" + encodeURIComponent(job.id) + "/model");
    const blob = await response.blob();
    const disposition = response.headers.get("Content-Disposition") || "";
    const match = /filename="?([^";]+)"?/.exec(disposition);
    const name = match ? match[1] : `neuenh-${job.id}.zip`;
    const url = URL.createObjectURL(blob);
    const a = el("a", { href: url, download: name, hidden: true });
    document.body.appendChild(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 60000);
    const round = response.headers.get("X-Neuenh-Round");
    note.textContent = `Downloaded ${name} (${(blob.size / 1024).toFixed(1)} KB${round !== null ? ", round " + round : ""}).`;
  } catch (err) {
    if (err instanceof ApiError && err.status === 401) { askToken(err.message); return; }
    note.className = "note bad";
    note.textContent = "Download failed: " + (err instanceof Error ? err.message : String(err));
  } finally {
    button.disabled = !S.job || S.job.last_round === null;
  }
}

async function cancel() {
  const job = S.job;
  if (!job || job.terminal) return;
  if (!S.cancelArmed) {
    S.cancelArmed = true;
    $("cancel").textContent = "Really cancel?";
    setTimeout(() => { S.cancelArmed = false; if (S.job) renderJob(); }, 4000);
    return;
  }
  S.cancelArmed = false;
  try {
    await request("/jobs/" + encodeURIComponent(job.id) + "/cancel", { method: "POST" });
  } catch (err) {
    handleError(err);
  }
  pollJob();
  pollList();
}

async function cancelPlan() {
  const id = planSelected();
  if (!id) return;
  try {
    if (!(await cancelPlanClicked(id))) return;
  } catch (err) {
    handleError(err);
  }
  pollPlan();
  pollList();
}

function start() {
  S.needsToken = false;
  $("forget-token").hidden = !token();
  pollList();
  pollPlan();
  if (S.selected) {
    $("job").hidden = false;
    pollJob();
  }
}

function main() {
  $("auth-form").addEventListener("submit", (ev) => {
    ev.preventDefault();
    const input = /** @type {HTMLInputElement} */ ($("token"));
    const value = input.value.trim();
    if (!value) return;
    setToken(value);
    input.value = "";
    $("auth-error").hidden = true;
    $("auth").hidden = true;
    start();
  });
  $("forget-token").addEventListener("click", () => {
    setToken("");
    stopTimers();
    start();
  });
  $("download").addEventListener("click", download);
  $("cancel").addEventListener("click", cancel);
  $("plan-cancel").addEventListener("click", cancelPlan);
  window.addEventListener("hashchange", () => selectFromHash(true));
  selectFromHash(false);
  start();
}

main();  // a module runs after the document is parsed, like a deferred script
