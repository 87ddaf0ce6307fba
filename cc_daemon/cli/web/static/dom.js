// The page's elements: made with their attributes and children, text that wraps as a
// whole or between words only. No network, no state.

export function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) if (v !== undefined) node.setAttribute(k, v);
  for (const c of children) if (c !== undefined && c !== null) node.append(c);
  return node;
}
// A chunk of text that wraps as a whole: no line ever breaks inside it.
export function chunk(text, cls) { return el("span", { class: cls ? `chunk ${cls}` : "chunk" }, text); }
// Text whose lines break only between words: a path may also break after one of its
// slashes (a hyphen is a place to break already), never inside a name.
export function prose(text) {
  const out = document.createDocumentFragment();
  String(text).split(/(?<=\/)/).forEach((piece, i) => {
    if (i) out.append(el("wbr"));
    out.append(piece);
  });
  return out;
}
