// The studio's REST API (with the token when the server needs one) and two DOM helpers every panel uses.

const params = new URLSearchParams(location.search);
export const TOKEN = params.get("token") || sessionStorage.getItem("studio-token") || "";
if (TOKEN) sessionStorage.setItem("studio-token", TOKEN);

export async function api(method, path, body) {
  // X-Studio-Request: the server refuses state-changing requests without it (or a JSON body), which
  // no cross-site form can send.
  const headers = TOKEN ? { "X-Studio-Token": TOKEN, "X-Studio-Request": "1" } : { "X-Studio-Request": "1" };
  const init = { method, headers };
  if (body instanceof Blob) { init.body = body; headers["Content-Type"] = "application/octet-stream"; }
  else if (body !== undefined) { init.body = JSON.stringify(body); headers["Content-Type"] = "application/json"; }
  const r = await fetch(path, init);
  const data = r.status === 204 ? null : await r.json();
  if (!r.ok) throw new Error((data && data.detail && (typeof data.detail === "string" ? data.detail : JSON.stringify(data.detail))) || r.statusText);
  return data;
}

export const withToken = (url) => (TOKEN ? `${url}${url.includes("?") ? "&" : "?"}token=${encodeURIComponent(TOKEN)}` : url);
export const $ = (id) => document.getElementById(id);
export const el = (tag, attrs = {}, ...children) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) (k.startsWith("on") ? e.addEventListener(k.slice(2), v) : e.setAttribute(k, v));
  for (const c of children) e.append(c);
  return e;
};
