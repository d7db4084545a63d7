// @ts-check
/* The chart: every candidate's validation loss per round, as SVG, the winners joined by a path. */

import { el, svg } from "./dom.js";
import { fmtLoss } from "./format.js";
import { lossAxis } from "./scale.js";

/** @typedef {import("./types.js").Round} Round */

const W = 1000, H = 300;
const M = { l: 78, r: 18, t: 30, b: 40 };

/** The chart for `rounds` (oldest first), or a note while there is none.
 * @param {Round[]} rounds @param {boolean} hasJob @returns {Element} */
export function lossChart(rounds, hasJob) {
  if (!rounds.length) return el("p", { class: "empty", text: hasJob ? "The chart fills in as rounds are committed." : "" });
  const losses = [];
  for (const r of rounds) for (const c of r.candidates) if (c.ok && Number.isFinite(c.val_loss)) losses.push(/** @type {number} */ (c.val_loss));
  const axis = lossAxis(losses, M.t, H - M.b);
  const first = rounds[0].round, last = rounds[rounds.length - 1].round;
  const n = Math.max(last - first + 1, 1);
  const band = (W - M.l - M.r) / n;
  const x = (/** @type {number} */ r) => M.l + band * (r - first + 0.5);

  const root = svg("svg", { viewBox: `0 0 ${W} ${H}`, role: "img", "aria-label": "validation loss of every candidate per round", preserveAspectRatio: "xMidYMid meet" });
  for (const t of axis.ticks) {
    const yy = axis.y(t);
    if (yy < M.t - 0.5 || yy > H - M.b + 0.5) continue;
    root.appendChild(svg("line", { x1: M.l, x2: W - M.r, y1: yy, y2: yy, class: "grid" }));
    root.appendChild(svg("text", { x: M.l - 8, y: yy + 4, class: "tick", "text-anchor": "end" }, axis.label(t)));
  }
  const every = Math.max(1, Math.ceil(n / 24));  // thin the round labels when there are many rounds
  for (let r = first; r <= last; r++) {
    if (r > first && n <= 40) root.appendChild(svg("line", { x1: x(r) - band / 2, x2: x(r) - band / 2, y1: M.t, y2: H - M.b, class: "sep" }));
    if ((r - first) % every === 0) {
      root.appendChild(svg("text", { x: x(r), y: H - M.b + 18, class: "tick", "text-anchor": "middle" }, n <= 8 ? `round ${r}` : String(r)));
    }
  }
  if (n > 8) root.appendChild(svg("text", { x: W - M.r, y: H - 4, class: "label", "text-anchor": "end" }, "round"));
  root.appendChild(svg("line", { x1: M.l, x2: W - M.r, y1: H - M.b, y2: H - M.b, class: "axis" }));
  root.appendChild(svg("line", { x1: M.l, x2: M.l, y1: M.t, y2: H - M.b, class: "axis" }));
  const mid = M.t + (H - M.t - M.b) / 2;
  root.appendChild(svg("text", { x: 16, y: mid, class: "label y-label", "text-anchor": "middle", transform: `rotate(-90 16 ${mid})` },
    "validation loss" + (axis.log ? " (log)" : "")));

  // the candidates, spread across their round's band in the order the history lists them
  const points = svg("g", { class: "points" });
  /** @type {[number, number, string][]} */
  const winners = [];
  const failedY = M.t - 14;
  let anyFailed = false;
  for (const r of rounds) {
    const k = r.candidates.length;
    const spread = Math.min(band * 0.62, 14 * k);
    r.candidates.forEach((c, i) => {
      const cx = x(r.round) + (k > 1 ? (i / (k - 1) - 0.5) * spread : 0);
      const label = `round ${r.round} · ${c.state} (${c.change})`;
      if (!c.ok || c.val_loss === null || !Number.isFinite(c.val_loss)) {
        anyFailed = true;
        const s = 4.5;
        points.appendChild(svg("path", { d: `M${cx - s} ${failedY - s}L${cx + s} ${failedY + s}M${cx + s} ${failedY - s}L${cx - s} ${failedY + s}`, class: "pt failed", "data-state": c.state, "data-round": r.round },
          svg("title", {}, `${label}: failed${c.error ? " — " + c.error : ""}`)));
        return;
      }
      const cls = "pt" + (c.winner ? " winner" : "") + (c.state === r.parent_state ? " stay" : "");
      const cy = axis.y(c.val_loss);
      if (c.winner) winners.push([cx, cy, c.change]);
      points.appendChild(svg("circle", { cx, cy, r: c.winner ? 6.5 : 4.2, class: cls, "data-state": c.state, "data-round": r.round, "data-loss": c.val_loss },
        svg("title", {}, `${label}: val loss ${fmtLoss(c.val_loss)}`
          + (c.fit_score !== null && c.fit_score !== undefined ? `, fit score ${fmtLoss(c.fit_score)}` : "")
          + (c.winner ? " — winner" : ""))));
    });
  }
  if (winners.length > 1) {
    root.appendChild(svg("polyline", { points: winners.map((p) => p[0].toFixed(1) + "," + p[1].toFixed(1)).join(" "), class: "winner-path" }));
  }
  for (const [cx, cy, change] of n <= 10 ? winners : []) {
    root.appendChild(svg("text", { x: cx + 9, y: cy - 9, class: "win-label" }, change));
  }
  if (anyFailed) root.appendChild(svg("text", { x: M.l - 8, y: failedY + 4, class: "tick fail-label", "text-anchor": "end" }, "failed"));
  root.appendChild(points);
  for (const c of Array.from(points.querySelectorAll(".winner"))) points.appendChild(c);  // winners on top
  return root;
}
