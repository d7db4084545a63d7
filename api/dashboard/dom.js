// @ts-check
/* Building DOM nodes. Everything from the API goes in as text (textContent / text nodes), never HTML. */

const SVG_NS = "http://www.w3.org/2000/svg";

/** @typedef {Record<string, unknown> | null | undefined} Attrs */
/** @typedef {Node | string | number | null | undefined | false} Child */

/** @param {string} id @returns {HTMLElement} */
export const $ = (id) => /** @type {HTMLElement} */ (document.getElementById(id));

/** An HTML element: attribute "text" sets its text, "onX" adds a listener, false/null are left out.
 * @param {string} tag @param {Attrs} attrs @param {...(Child | Child[])} children */
export function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  setAttrs(node, attrs);
  append(node, children);
  return node;
}

/** An SVG element, as `el`.
 * @param {string} tag @param {Attrs} attrs @param {...(Child | Child[])} children */
export function svg(tag, attrs, ...children) {
  const node = document.createElementNS(SVG_NS, tag);
  setAttrs(node, attrs);
  append(node, children);
  return node;
}

/** @param {Element} node @param {Attrs} attrs */
function setAttrs(node, attrs) {
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === null || v === undefined || v === false) continue;
    if (k === "text") node.textContent = String(v);
    else if (k.startsWith("on")) node.addEventListener(k.slice(2), /** @type {EventListener} */ (v));
    else node.setAttribute(k, v === true ? "" : String(v));
  }
}

/** @param {Node} node @param {(Child | Child[])[]} children */
function append(node, children) {
  for (const c of children.flat()) {
    if (c === null || c === undefined || c === false) continue;
    node.appendChild(typeof c === "string" || typeof c === "number" ? document.createTextNode(String(c)) : c);
  }
}

/** Removes every child. @template {Node} T @param {T} node @returns {T} */
export function clear(node) {
  while (node.firstChild) node.removeChild(node.firstChild);
  return node;
}

/** A position name with break opportunities after its operators (the text stays the name).
 * @param {string} name */
export function breakable(name) {
  const frag = document.createDocumentFragment();
  for (const part of name.split(/(?<=[*+])/)) {
    frag.appendChild(document.createTextNode(part));
    frag.appendChild(document.createElement("wbr"));
  }
  return frag;
}
