/* neuenh dashboard: the jobs of this service and, for the job named in the URL hash
 * (#job=<id>), its trail through the hypercube, every candidate's validation loss, the running
 * round's progress and the model download.
 *
 * Plain JS, no dependencies and no external URL: it works offline. Everything coming from the API
 * is inserted as text (textContent / createTextNode), never as HTML.
 *
 * Polling: the job list every LIST_MS; the selected job (GET /v1/jobs/{id}) and its history
 * (GET .../history?since_round=k, appending the rounds it returns) every JOB_MS until the job is
 * terminal. A 401 shows the token form; the token is kept in localStorage and sent as a bearer
 * header, so the model download goes through fetch and a blob URL too.
 */
"use strict";

(function () {
  const API = "/v1";
  const LIST_MS = 3000;
  const JOB_MS = 2000;
  const TOKEN_KEY = "neuenh.token";
  const SVG_NS = "http://www.w3.org/2000/svg";

  // ---------------------------------------------------------------------------------------------
  // small helpers
  const $ = (id) => document.getElementById(id);

  function el(tag, attrs, ...children) {
    const node = document.createElement(tag);
    setAttrs(node, attrs);
    append(node, children);
    return node;
  }

  function svg(tag, attrs, ...children) {
    const node = document.createElementNS(SVG_NS, tag);
    setAttrs(node, attrs);
    append(node, children);
    return node;
  }

  function setAttrs(node, attrs) {
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === null || v === undefined || v === false) continue;
      if (k === "text") node.textContent = String(v);
      else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
      else node.setAttribute(k, v === true ? "" : String(v));
    }
  }

  function append(node, children) {
    for (const c of children.flat()) {
      if (c === null || c === undefined || c === false) continue;
      node.appendChild(typeof c === "string" || typeof c === "number" ? document.createTextNode(String(c)) : c);
    }
  }

  function clear(node) {
    while (node.firstChild) node.removeChild(node.firstChild);
    return node;
  }

  function fmtLoss(x) {
    if (x === null || x === undefined || !Number.isFinite(x)) return "–";
    if (x !== 0 && (Math.abs(x) < 1e-3 || Math.abs(x) >= 1e4)) return x.toExponential(3);
    return x.toPrecision(4);
  }

  function fmtSeconds(s) {
    if (!Number.isFinite(s)) return "–";
    if (s < 60) return s.toFixed(s < 10 ? 1 : 0) + " s";
    const m = Math.floor(s / 60), r = Math.round(s % 60);
    if (m < 60) return `${m} min ${r} s`;
    return `${Math.floor(m / 60)} h ${m % 60} min`;
  }

  function fmtTime(iso) {
    const d = new Date(iso);
    if (Number.isNaN(d.getTime())) return String(iso);
    const pad = (n) => String(n).padStart(2, "0");
    return `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())} ${pad(d.getHours())}:${pad(d.getMinutes())}:${pad(d.getSeconds())}`;
  }

  function isOperator(name) { return /[*+]/.test(name); }

  /** Positions (indices) where two state strings differ. */
  function diff(a, b) {
    const out = [];
    for (let i = 0; i < Math.max(a.length, b.length); i++) if (a[i] !== b[i]) out.push(i);
    return out;
  }

  function describeChange(parent, winner, positions) {
    const changed = diff(parent, winner);
    if (!changed.length) return "stay";
    return changed.map((i) => `${positions[i] || "#" + i} ${parent[i]}→${winner[i]}`).join(", ");
  }

  /** "+F" (made neural), "−F" (back to analytical), "F→2" (another choice), or "stay". */
  function shortChange(parent, state, positions) {
    const changed = diff(parent, state);
    if (!changed.length) return "stay";
    return changed.map((i) => {
      const name = positions[i] || "#" + i;
      return state[i] === "0" ? "−" + name : state[i] === "1" && parent[i] === "0" ? "+" + name : `${name}→${state[i]}`;
    }).join(" ");
  }

  function neuralNames(state, positions) {
    const out = [];
    for (let i = 0; i < state.length; i++) if (state[i] !== "0") out.push(positions[i] || "#" + i);
    return out;
  }

  /** A position name with break opportunities after its operators (the text stays the name). */
  function breakable(name) {
    const frag = document.createDocumentFragment();
    for (const part of name.split(/(?<=[*+])/)) {
      frag.appendChild(document.createTextNode(part));
      frag.appendChild(document.createElement("wbr"));
    }
    return frag;
  }

  // ---------------------------------------------------------------------------------------------
  // API access
  class ApiError extends Error {
    constructor(status, detail) {
      super(detail);
      this.status = status;
    }
  }

  function token() {
    try { return localStorage.getItem(TOKEN_KEY) || ""; } catch (e) { return ""; }
  }

  function setToken(value) {
    try {
      if (value) localStorage.setItem(TOKEN_KEY, value);
      else localStorage.removeItem(TOKEN_KEY);
    } catch (e) { /* storage disabled: the token lives for this page only */ }
    memoryToken = value;
  }

  let memoryToken = "";

  function headers() {
    const t = token() || memoryToken;
    return t ? { Authorization: "Bearer " + t } : {};
  }

  async function request(path, options) {
    let response;
    try {
      response = await fetch(API + path, { cache: "no-store", ...options, headers: { ...headers(), ...((options || {}).headers || {}) } });
    } catch (e) {
      throw new ApiError(0, "cannot reach the service (" + e.message + ")");
    }
    if (!response.ok) {
      let detail = response.statusText || "error";
      try {
        const body = await response.json();
        if (typeof body.detail === "string") detail = body.detail;
        else if (body.detail !== undefined) detail = JSON.stringify(body.detail);
      } catch (e) { /* not JSON */ }
      throw new ApiError(response.status, `${response.status}: ${detail}`);
    }
    return response;
  }

  const getJSON = async (path) => (await request(path)).json();

  // ---------------------------------------------------------------------------------------------
  // state
  const S = {
    jobs: [],
    selected: null,     // job id from the hash
    job: null,          // JobPublic of the selected job
    rounds: [],         // RoundPublic[], oldest first
    nextSince: 0,
    historyTerminal: false,
    generation: 0,      // bumps when the selection changes: late answers for another job are dropped
    listTimer: null,
    jobTimer: null,
    needsToken: false,
    cancelArmed: false,
  };

  function showError(message) {
    const box = $("error");
    box.textContent = message || "";
    box.hidden = !message;
  }

  function setConn(text, cls) {
    const c = $("conn");
    c.textContent = text;
    c.className = "conn-state " + (cls || "");
  }

  function handleError(err) {
    if (err instanceof ApiError && err.status === 401) {
      askToken(err.message);
      return;
    }
    setConn("offline", "bad");
    showError(err.message || String(err));
  }

  function askToken(message) {
    S.needsToken = true;
    stopTimers();
    $("auth").hidden = false;
    $("jobs-panel").hidden = true;
    $("job").hidden = true;
    setConn("needs a token", "bad");
    const had = Boolean(token() || memoryToken);
    const note = $("auth-error");
    note.textContent = had ? "The token was refused (" + message + "). Try again." : "";
    note.hidden = !had;
    $("token").focus();
  }

  function stopTimers() {
    clearTimeout(S.listTimer);
    clearTimeout(S.jobTimer);
    S.listTimer = S.jobTimer = null;
  }

  // ---------------------------------------------------------------------------------------------
  // the job list
  async function pollList() {
    clearTimeout(S.listTimer);
    try {
      const page = await getJSON("/jobs?limit=50");
      S.jobs = page.jobs;
      showError("");
      setConn("live", "ok");
      renderJobs();
    } catch (err) {
      handleError(err);
    }
    if (!S.needsToken) S.listTimer = setTimeout(pollList, LIST_MS);
  }

  function badge(status) {
    return el("span", { class: "badge s-" + String(status).toLowerCase(), text: status });
  }

  function miniProgress(job) {
    if (job.progress && job.progress.total > 0) {
      const p = job.progress;
      const pct = Math.round((100 * p.done) / p.total);
      return el("div", { class: "mini" },
        el("div", { class: "mini-bar" }, el("div", { class: "mini-fill", style: `width:${pct}%` })),
        el("span", { class: "muted", text: `round ${p.round} · ${p.done}/${p.total}` }));
    }
    if (job.status === "QUEUED") return el("span", { class: "muted", text: "waiting" });
    if (job.status === "PREPARING") return el("span", { class: "muted", text: "preparing data" });
    const ends = { CONVERGED: "converged", STOPPED: "finished", CANCELLED: "cancelled", FAILED: "failed" };
    return el("span", { class: "muted", text: ends[job.status] || "–" });
  }

  function renderJobs() {
    $("auth").hidden = true;
    $("jobs-panel").hidden = false;
    const body = clear($("jobs").tBodies[0]);
    for (const job of S.jobs) {
      const href = "#job=" + encodeURIComponent(job.id);
      const tr = el("tr", { "data-job": job.id, class: job.id === S.selected ? "selected" : null },
        el("td", {}, el("a", { href, title: job.id, text: job.name || job.id.slice(0, 8) }),
          job.name ? el("span", { class: "muted id", text: " " + job.id.slice(0, 8) }) : null),
        el("td", { text: job.model }),
        el("td", {}, badge(job.status)),
        el("td", { class: "num", text: job.last_round === null ? "0" : String(job.last_round + 1) }),
        el("td", { class: "mono", text: job.current_state || "–" }),
        el("td", {}, miniProgress(job)),
        el("td", { class: "muted", text: fmtTime(job.created_at) }));
      tr.addEventListener("click", (ev) => {
        if (ev.target.closest("a")) return;
        location.hash = href;
      });
      body.appendChild(tr);
    }
    $("jobs-empty").hidden = S.jobs.length > 0;
    $("jobs").hidden = S.jobs.length === 0;
    $("jobs-count").textContent = S.jobs.length ? `${S.jobs.length} job${S.jobs.length > 1 ? "s" : ""}, newest first` : "";
  }

  // ---------------------------------------------------------------------------------------------
  // the selected job
  function selectFromHash(poll) {
    const params = new URLSearchParams(location.hash.replace(/^#/, ""));
    const id = params.get("job");
    if (id === S.selected) return;
    S.selected = id;
    S.generation += 1;
    S.job = null;
    S.rounds = [];
    S.nextSince = 0;
    S.historyTerminal = false;
    S.cancelArmed = false;
    clearTimeout(S.jobTimer);
    $("download-note").hidden = true;
    $("job-error").hidden = true;
    for (const tr of $("jobs").tBodies[0].rows) tr.classList.toggle("selected", tr.dataset.job === id);
    if (!id) {
      $("job").hidden = true;
      return;
    }
    $("job").hidden = false;
    $("job-title").textContent = "job " + id;
    $("job-meta").textContent = "loading…";
    renderJob();
    if (poll !== false && !S.needsToken) pollJob();
  }

  async function pollJob() {
    clearTimeout(S.jobTimer);
    const gen = S.generation;
    const id = S.selected;
    if (!id) return;
    let again = true;
    try {
      const path = "/jobs/" + encodeURIComponent(id);
      const [job, history] = await Promise.all([
        getJSON(path),
        getJSON(path + "/history?since_round=" + S.nextSince),
      ]);
      if (gen !== S.generation) return;
      S.job = job;
      const known = new Set(S.rounds.map((r) => r.round));
      for (const r of history.rounds) if (!known.has(r.round)) S.rounds.push(r);
      S.rounds.sort((a, b) => a.round - b.round);
      S.nextSince = Math.max(S.nextSince, history.next_since_round);
      S.historyTerminal = history.terminal;
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

  function positionsOf() {
    const job = S.job;
    if (job && job.positions && job.positions.length) return job.positions;
    const n = (job && job.current_state ? job.current_state.length : 0) || (S.rounds[0] ? S.rounds[0].winner_state.length : 0);
    return Array.from({ length: n }, (_, i) => "#" + i);
  }

  function renderJob() {
    const job = S.job;
    if (!job) {
      renderTrail();
      renderChart();
      return;
    }
    const positions = positionsOf();
    $("job-title").textContent = job.name || "job " + job.id.slice(0, 8);
    const spec = job.spec || {};
    const search = spec.search || {};
    const bits = [job.id, job.model, `created ${fmtTime(job.created_at)}`];
    if (search.radius !== undefined) bits.push(`radius ${search.radius}`);
    if (search.epochs_per_round !== undefined) bits.push(`${search.epochs_per_round} epochs/round`);
    if (search.max_rounds !== undefined) bits.push(`max ${search.max_rounds} rounds`);
    if (Array.isArray(spec.data)) bits.push(spec.data.map((d) => d.source).join(" + "));
    $("job-meta").textContent = bits.join(" · ");
    const status = $("job-status");
    status.textContent = job.status;
    status.className = "badge s-" + job.status.toLowerCase();

    const err = $("job-error");
    err.textContent = job.error ? "Error: " + job.error : "";
    err.hidden = !job.error;

    const cancel = $("cancel");
    cancel.hidden = job.terminal;
    cancel.textContent = S.cancelArmed ? "Really cancel?" : "Cancel job";

    const download = $("download");
    download.disabled = job.last_round === null;
    download.title = job.last_round === null ? "available once round 0 is committed" : "";

    // summary cards
    const last = S.rounds[S.rounds.length - 1];
    $("card-rounds").textContent = String(S.rounds.length);
    $("card-loss").textContent = last ? fmtLoss(last.winner_val_loss) : "–";
    const first = S.rounds[0];
    const stay0 = first && first.candidates.find((c) => c.state === first.parent_state && c.ok);
    if (last && stay0 && stay0.val_loss > 0) {
      const gain = 1 - last.winner_val_loss / stay0.val_loss;
      $("card-gain").textContent = (gain >= 0 ? "−" : "+") + Math.abs(100 * gain).toFixed(1) + "% loss";
      $("card-gain").title = `plain ${job.model} trained the same epochs in round 0: ${fmtLoss(stay0.val_loss)}`;
    } else {
      $("card-gain").textContent = "–";
    }
    const state = job.current_state || (last && last.winner_state);
    $("card-neural").textContent = state ? `${neuralNames(state, positions).length} of ${positions.length}` : "–";

    renderProgress(job);
    renderTrail();
    renderChart();
    renderFinal(state, positions);
  }

  function renderProgress(job) {
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

  function renderTrail() {
    const table = $("trail");
    const positions = positionsOf();
    const head = clear(table.tHead);
    const body = clear(table.tBodies[0]);
    const foot = clear(table.tFoot);
    const nodes = positions.filter((n) => !isOperator(n)).length;
    if (positions.length) {
      head.appendChild(el("tr", { class: "groups" },
        el("th", { colspan: 1 }),
        nodes ? el("th", { colspan: nodes, class: "group", text: "terms" }) : null,
        positions.length - nodes ? el("th", { colspan: positions.length - nodes, class: "group ops", text: "operators" }) : null,
        el("th", { colspan: 3 })));
      head.appendChild(el("tr", {},
        el("th", { class: "num", text: "Round" }),
        positions.map((name, i) => el("th", { class: "pos" + (isOperator(name) ? " op" : ""), "data-index": i, title: name }, breakable(name))),
        el("th", { text: "Change that won" }),
        el("th", { class: "num", text: "Winner val loss" }),
        el("th", { class: "num", text: "Wall" })));
    }
    let prevLoss = null;
    for (const r of S.rounds) {
      const changed = new Set(diff(r.parent_state, r.winner_state));
      const cells = [];
      for (let i = 0; i < positions.length; i++) {
        const d = r.winner_state[i] || "?";
        cells.push(el("td", {
          class: `digit d${Math.min(Number(d) || 0, 3)}` + (changed.has(i) ? " flipped" : ""),
          title: `${positions[i]}: ${d === "0" ? "analytical" : d === "1" ? "neural module" : "choice " + d}` +
            (changed.has(i) ? ` (was ${r.parent_state[i]})` : ""),
          text: d,
        }));
      }
      let delta = null;
      if (prevLoss !== null && prevLoss > 0) {
        const rel = (r.winner_val_loss - prevLoss) / prevLoss;
        delta = el("span", { class: "delta " + (rel <= 0 ? "down" : "up"), text: ` ${rel <= 0 ? "−" : "+"}${Math.abs(100 * rel).toFixed(1)}%` });
      }
      prevLoss = r.winner_val_loss;
      const change = changed.size
        ? el("td", { class: "change" }, describeChange(r.parent_state, r.winner_state, positions))
        : el("td", { class: "change stay" }, r.extra && r.extra.polish ? "polish: trained on, lr decaying"
          : r.converged ? "stay: converged" : "stay");
      body.appendChild(el("tr", { "data-round": r.round, "data-state": r.winner_state },
        el("td", { class: "num", text: String(r.round) }),
        cells,
        change,
        el("td", { class: "num mono" }, fmtLoss(r.winner_val_loss), delta),
        el("td", { class: "num muted", text: fmtSeconds(r.wall_s) })));
    }
    const p = S.job && !S.job.terminal ? S.job.progress : null;
    if (p && p.total > 0 && !S.rounds.some((r) => r.round === p.round)) {
      foot.appendChild(el("tr", { class: "pending" },
        el("td", { class: "num", text: String(p.round) }),
        el("td", { colspan: positions.length + 3, text: `training… ${p.done}/${p.total} candidates` + (p.best_val_loss !== null ? `, best ${fmtLoss(p.best_val_loss)}` : "") })));
    }
    $("trail-empty").hidden = S.rounds.length > 0 || !S.job;
    table.hidden = positions.length === 0;
  }

  // ---------------------------------------------------------------------------------------------
  // the chart: every candidate's validation loss per round, drawn as SVG
  function niceLinearTicks(lo, hi, count) {
    const span = hi - lo || Math.abs(hi) || 1;
    const raw = span / Math.max(count, 1);
    const mag = Math.pow(10, Math.floor(Math.log10(raw)));
    const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((s) => span / s <= count) || 10 * mag;
    const ticks = [];
    for (let t = Math.ceil(lo / step) * step; t <= hi + step * 1e-9; t += step) ticks.push(Number(t.toPrecision(12)));
    return ticks;
  }

  /** A tick label with just the decimals its spacing needs. */
  function fmtTick(t, step) {
    if (t !== 0 && (Math.abs(t) < 1e-3 || Math.abs(t) >= 1e4)) return t.toExponential(1);
    const decimals = Math.max(0, Math.min(8, -Math.floor(Math.log10(step || Math.abs(t) || 1) + 1e-9)));
    return t.toFixed(decimals);
  }

  function logTicks(lo, hi) {
    const ticks = [];
    for (let e = Math.floor(Math.log10(lo)); e <= Math.ceil(Math.log10(hi)); e++) {
      for (const m of [1, 2, 5]) {
        const t = m * Math.pow(10, e);
        if (t >= lo && t <= hi) ticks.push(t);
      }
    }
    return ticks.length >= 2 ? ticks : null;
  }

  function renderChart() {
    const box = clear($("chart"));
    const rounds = S.rounds;
    if (!rounds.length) {
      box.appendChild(el("p", { class: "empty", text: S.job ? "The chart fills in as rounds are committed." : "" }));
      return;
    }
    const positions = positionsOf();
    const W = 1000, H = 300;
    const m = { l: 78, r: 18, t: 30, b: 40 };
    const losses = [];
    for (const r of rounds) for (const c of r.candidates) if (c.ok && Number.isFinite(c.val_loss)) losses.push(c.val_loss);
    let lo = losses.length ? Math.min(...losses) : 0.1;
    let hi = losses.length ? Math.max(...losses) : 1;
    const useLog = lo > 0 && hi / lo > 4;
    let y, ticks, tickLabel;
    if (useLog) {
      const a = Math.log10(lo) - 0.05 * (Math.log10(hi) - Math.log10(lo)), b = Math.log10(hi) + 0.05 * (Math.log10(hi) - Math.log10(lo));
      lo = Math.pow(10, a); hi = Math.pow(10, b);
      y = (v) => m.t + (H - m.t - m.b) * (1 - (Math.log10(v) - a) / (b - a));
      ticks = logTicks(lo, hi) || [lo, hi];
      tickLabel = (t) => fmtTick(t, t);
    } else {
      const pad = (hi - lo) * 0.08 || Math.abs(hi) * 0.05 || 0.01;
      lo -= pad; hi += pad;
      y = (v) => m.t + (H - m.t - m.b) * (1 - (v - lo) / (hi - lo));
      ticks = niceLinearTicks(lo, hi, 6);
      tickLabel = (t) => fmtTick(t, ticks.length > 1 ? ticks[1] - ticks[0] : t);
    }
    const first = rounds[0].round, lastR = rounds[rounds.length - 1].round;
    const n = Math.max(lastR - first + 1, 1);
    const band = (W - m.l - m.r) / n;
    const x = (r) => m.l + band * (r - first + 0.5);

    const root = svg("svg", { viewBox: `0 0 ${W} ${H}`, role: "img", "aria-label": "validation loss of every candidate per round", preserveAspectRatio: "xMidYMid meet" });
    // grid and axes
    for (const t of ticks) {
      const yy = y(t);
      if (yy < m.t - 0.5 || yy > H - m.b + 0.5) continue;
      root.appendChild(svg("line", { x1: m.l, x2: W - m.r, y1: yy, y2: yy, class: "grid" }));
      root.appendChild(svg("text", { x: m.l - 8, y: yy + 4, class: "tick", "text-anchor": "end" }, tickLabel(t)));
    }
    const every = Math.max(1, Math.ceil(n / 24));  // thin the round labels when there are many rounds
    for (let r = first; r <= lastR; r++) {
      if (r > first && n <= 40) root.appendChild(svg("line", { x1: x(r) - band / 2, x2: x(r) - band / 2, y1: m.t, y2: H - m.b, class: "sep" }));
      if ((r - first) % every === 0) {
        root.appendChild(svg("text", { x: x(r), y: H - m.b + 18, class: "tick", "text-anchor": "middle" }, n <= 8 ? `round ${r}` : String(r)));
      }
    }
    if (n > 8) root.appendChild(svg("text", { x: W - m.r, y: H - 4, class: "label", "text-anchor": "end" }, "round"));
    root.appendChild(svg("line", { x1: m.l, x2: W - m.r, y1: H - m.b, y2: H - m.b, class: "axis" }));
    root.appendChild(svg("line", { x1: m.l, x2: m.l, y1: m.t, y2: H - m.b, class: "axis" }));
    root.appendChild(svg("text", { x: 16, y: m.t + (H - m.t - m.b) / 2, class: "label y-label", "text-anchor": "middle", transform: `rotate(-90 16 ${m.t + (H - m.t - m.b) / 2})` },
      "validation loss" + (useLog ? " (log)" : "")));

    // the candidates, spread across their round's band in the order the history lists them
    const points = svg("g", { class: "points" });
    const winners = [];
    const failedY = m.t - 14;
    let anyFailed = false;
    for (const r of rounds) {
      const k = r.candidates.length;
      const spread = Math.min(band * 0.62, 14 * k);
      r.candidates.forEach((c, i) => {
        const cx = x(r.round) + (k > 1 ? (i / (k - 1) - 0.5) * spread : 0);
        const change = describeChange(r.parent_state, c.state, positions);
        const label = `round ${r.round} · ${c.state} (${change})`;
        if (!c.ok || !Number.isFinite(c.val_loss)) {
          anyFailed = true;
          const s = 4.5;
          points.appendChild(svg("path", { d: `M${cx - s} ${failedY - s}L${cx + s} ${failedY + s}M${cx + s} ${failedY - s}L${cx - s} ${failedY + s}`, class: "pt failed", "data-state": c.state, "data-round": r.round },
            svg("title", {}, `${label}: failed${c.error ? " — " + c.error : ""}`)));
          return;
        }
        const stay = c.state === r.parent_state;
        const cls = "pt" + (c.winner ? " winner" : "") + (stay ? " stay" : "");
        const cy = y(c.val_loss);
        if (c.winner) winners.push([cx, cy, shortChange(r.parent_state, c.state, positions)]);
        points.appendChild(svg("circle", { cx, cy, r: c.winner ? 6.5 : 4.2, class: cls, "data-state": c.state, "data-round": r.round, "data-loss": c.val_loss },
          svg("title", {}, `${label}: val loss ${fmtLoss(c.val_loss)}${c.winner ? " — winner" : ""}`)));
      });
    }
    // the winners' path and what each winner changed
    if (winners.length > 1) {
      root.appendChild(svg("polyline", { points: winners.map((p) => p[0].toFixed(1) + "," + p[1].toFixed(1)).join(" "), class: "winner-path" }));
    }
    for (const [cx, cy, change] of n <= 10 ? winners : []) {
      root.appendChild(svg("text", { x: cx + 9, y: cy - 9, class: "win-label" }, change));
    }
    if (anyFailed) root.appendChild(svg("text", { x: m.l - 8, y: failedY + 4, class: "tick fail-label", "text-anchor": "end" }, "failed"));
    root.appendChild(points);
    // winners drawn last so they sit on top
    for (const c of Array.from(points.querySelectorAll(".winner"))) points.appendChild(c);
    box.appendChild(root);
  }

  // ---------------------------------------------------------------------------------------------
  // the final (or current) model
  function renderFinal(state, positions) {
    const job = S.job;
    $("final-heading").textContent = job.terminal ? "Final model" : "Current model (last committed round)";
    const strip = clear($("final-state"));
    const text = $("final-text");
    if (!state) {
      text.textContent = "No model yet: it is available once round 0 is committed.";
      return;
    }
    strip.appendChild(el("span", { class: "mono state-code", text: state }));
    for (let i = 0; i < positions.length; i++) {
      const d = state[i] || "?";
      strip.appendChild(el("span", { class: `chip d${Math.min(Number(d) || 0, 3)}`, title: d === "0" ? "analytical" : d === "1" ? "neural module" : "choice " + d },
        el("span", { class: "chip-name", text: positions[i] }), el("span", { class: "chip-digit", text: d })));
    }
    const neural = neuralNames(state, positions);
    const last = S.rounds[S.rounds.length - 1];
    const parts = [neural.length ? `neural at ${neural.join(", ")}` : "all terms analytical"];
    if (last) parts.push(`validation loss ${fmtLoss(last.winner_val_loss)} after round ${last.round}`);
    if (job.status === "CONVERGED") parts.push("converged: no single change improved it further");
    else if (job.status === "STOPPED") parts.push("stopped at max_rounds");
    text.textContent = parts.join(" · ");
  }

  // ---------------------------------------------------------------------------------------------
  // actions
  async function download() {
    const job = S.job;
    if (!job) return;
    const button = $("download");
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
      note.textContent = "Download failed: " + err.message;
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

  function start() {
    S.needsToken = false;
    $("forget-token").hidden = !(token() || memoryToken);
    pollList();
    if (S.selected) {
      $("job").hidden = false;
      pollJob();
    }
  }

  document.addEventListener("DOMContentLoaded", () => {
    $("auth-form").addEventListener("submit", (ev) => {
      ev.preventDefault();
      const value = $("token").value.trim();
      if (!value) return;
      setToken(value);
      $("token").value = "";
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
    window.addEventListener("hashchange", () => selectFromHash(true));
    selectFromHash(false);
    start();
  });
})();
