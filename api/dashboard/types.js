// @ts-check
/* The API's answers as the dashboard reads them (api/schemas.py is the source of truth). */

/**
 * @typedef {{round: number, done: number, total: number, best_val_loss: number | null, state: string,
 *            elapsed_s: number, message: string}} Progress
 * @typedef {{id: string, name: string | null, model: string, status: string, terminal: boolean,
 *            error: string | null, created_at: string, last_round: number | null,
 *            current_state: string | null, spec: any, progress: Progress | null, positions: string[]}} Job
 * @typedef {{state: string, change: string, ok: boolean, winner: boolean, pruned: boolean,
 *            val_loss: number | null, error: string | null}} Candidate
 * @typedef {{round: number, kind: string, parent_state: string, winner_state: string, change: string,
 *            winner_val_loss: number, gain_over_start: number | null, converged: boolean,
 *            wall_s: number, candidates: Candidate[]}} Round
 * @typedef {{job_id: string, status: string, terminal: boolean, start_val_loss: number | null,
 *            gain_over_start: number | null, rounds: Round[], next_since_round: number}} History
 */

export {};
