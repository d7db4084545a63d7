// @ts-check
/* The API's answers as the dashboard reads them (api/schemas.py is the source of truth). */

/**
 * @typedef {{round: number, done: number, total: number, best_val_loss: number | null, state: string,
 *            elapsed_s: number, message: string, score: string}} Progress
 * @typedef {{id: string, name: string | null, model: string, status: string, terminal: boolean,
 *            error: string | null, reason: string | null, priority: number, used_wall_s: number,
 *            used_cpu_s: number, created_at: string, last_round: number | null,
 *            current_state: string | null, spec: any, progress: Progress | null, positions: string[],
 *            choices?: Record<string, string[]>}} Job
 * @typedef {{state: string, change: string, ok: boolean, winner: boolean, pruned: boolean,
 *            val_loss: number | null, fit_score?: number | null, error: string | null}} Candidate
 * @typedef {{round: number, kind: string, parent_state: string, winner_state: string, change: string,
 *            winner_val_loss: number, winner_fit_score?: number | null, gain_over_start: number | null, converged: boolean,
 *            wall_s: number, recovered: number, candidates: Candidate[], extra?: {stop_when?: string}}} Round
 * @typedef {{job_id: string, status: string, terminal: boolean, reason: string | null, score?: string,
 *            start_val_loss: number | null, gain_over_start: number | null, rounds: Round[],
 *            next_since_round: number}} History
 * @typedef {{job_id: string, candidates: number, cpus: number, gpus: number}} Holder
 * @typedef {{running_jobs: string[], max_running_jobs: number, holders: Holder[]}} Cluster
 * @typedef {{key: string, label: string, cost_ns: number}} PlanRung
 * @typedef {{name: string, weight: number, chosen: string, error: number, cost_ns: number,
 *            richest: {error: number, cost_ns: number}}} PlanMaterial
 * @typedef {{cost_ns: number, error: number}} FrameTotal
 * @typedef {{ladder: PlanRung[], materials: PlanMaterial[],
 *            totals: {plan: FrameTotal, richest: FrameTotal, cheapest: FrameTotal}}} PlanResult
 * @typedef {{id: string, name: string | null, status: string, terminal: boolean, error: string | null,
 *            created_at: string, materials_total: number | null, materials_done: number,
 *            progress: {message: string, step: number, steps: number} | null, plan: PlanResult | null,
 *            files: Record<string, string>}} Plan
 */

export {};
