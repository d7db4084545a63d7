// @ts-check
/* The /v1 API: fetch with the bearer token kept in localStorage, errors carrying the HTTP status. */

const API = "/v1";
const TOKEN_KEY = "neuenh.token";

export class ApiError extends Error {
  /** @param {number} status 0 when the service was not reached @param {string} detail */
  constructor(status, detail) {
    super(detail);
    this.status = status;
  }
}

let memoryToken = "";  // when localStorage is disabled the token lives for this page only

/** @returns {string} */
export function token() {
  try { return localStorage.getItem(TOKEN_KEY) || memoryToken; } catch (e) { return memoryToken; }
}

/** @param {string} value "" forgets it */
export function setToken(value) {
  try {
    if (value) localStorage.setItem(TOKEN_KEY, value);
    else localStorage.removeItem(TOKEN_KEY);
  } catch (e) { /* storage disabled */ }
  memoryToken = value;
}

/** A response with a 2xx status, or an ApiError with the service's `detail`.
 * @param {string} path below /v1 @param {RequestInit} [options] @returns {Promise<Response>} */
export async function request(path, options) {
  const t = token();
  const auth = t ? { Authorization: "Bearer " + t } : {};
  let response;
  try {
    response = await fetch(API + path, { cache: "no-store", ...options, headers: { ...auth, ...((options || {}).headers || {}) } });
  } catch (e) {
    throw new ApiError(0, "cannot reach the service (" + (e instanceof Error ? e.message : String(e)) + ")");
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

/** @param {string} path @returns {Promise<any>} */
export const getJSON = async (path) => (await request(path)).json();
