// canopen-gateway web console: plain JavaScript, no framework, no build step.
// Pages: index (overview + nodes table), node (one node, live), commission (writes, token),
// events (the event log), monitor (the bus monitor).
"use strict";

const page = document.body.dataset.page;

// ------------------------------------------------------------------ small helpers
function el(tag, attrs, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === null || v === undefined) continue;
    if (k === "class") e.className = v;
    else if (k.startsWith("data-")) e.setAttribute(k, v);
    else e[k] = v;
  }
  for (const c of children) {
    if (c === null || c === undefined) continue;
    e.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return e;
}

function fmtNumber(v) {
  if (typeof v !== "number") return v === null || v === undefined ? "" : String(v);
  if (Number.isInteger(v)) return String(v);
  return String(Number(v.toPrecision(7)));
}

function fmtAge(s) {
  if (s === null || s === undefined) return "never";
  if (s < 10) return s.toFixed(2) + " s";
  if (s < 120) return s.toFixed(1) + " s";
  if (s < 7200) return (s / 60).toFixed(1) + " min";
  return (s / 3600).toFixed(1) + " h";
}

function fmtTime(ts) {
  if (!ts) return "";
  const d = new Date(ts * 1000);
  return d.toLocaleString(undefined, { hour12: false });
}

function fmtUptime(s) {
  const d = Math.floor(s / 86400), h = Math.floor((s % 86400) / 3600);
  const m = Math.floor((s % 3600) / 60), sec = Math.floor(s % 60);
  return (d ? d + " d " : "") + (d || h ? h + " h " : "") + m + " min " + sec + " s";
}

// Quality is always written in words; the colour only repeats it.
const QUALITY_CLASS = { good: "good", stale: "stale", bad: "bad" };
function badge(word, kind) {
  return el("span", { class: "badge " + (kind || QUALITY_CLASS[word] || "info") }, word);
}

function setFacts(dl, pairs) {
  dl.replaceChildren();
  for (const [k, v] of pairs) {
    dl.append(el("dt", {}, k), el("dd", {}, v));
  }
}

async function getJSON(path) {
  const r = await fetch(path, { cache: "no-store" });
  if (!r.ok) throw new Error(path + ": HTTP " + r.status);
  return r.json();
}

// Operators' endpoints (journal, bus monitor, SDO reads, faults): with a token set on the
// gateway they need it. unlockOperator() asks for it once, logs in (POST /api/login sets a
// session cookie, which EventSource and links send too) and keeps it for the commissioning page.
const TOKEN_KEY = "canopen-gateway-token";

async function unlockOperator() {
  const s = await getJSON("/api/session");
  if (s.allowed) return true;
  if (!s.token_required) return false; // not from this machine without a token: the answer says why
  for (;;) {
    const token = sessionStorage.getItem(TOKEN_KEY) || window.prompt("The operators' token of this gateway (web.token):");
    if (!token) return false;
    const r = await fetch("/api/login", { method: "POST", headers: { "Authorization": "Bearer " + token } });
    if (r.ok) { sessionStorage.setItem(TOKEN_KEY, token); return true; }
    sessionStorage.removeItem(TOKEN_KEY);
    if (r.status !== 403) return false; // 429: too many wrong tokens; the next answer says so
  }
}

async function operatorFetch(url, opts) {
  let r = await fetch(url, opts);
  if ((r.status === 401 || r.status === 403) && await unlockOperator()) r = await fetch(url, opts);
  return r;
}

function setConn(text) {
  const c = document.getElementById("conn");
  if (c) c.textContent = text;
}

function liveStream(url, handlers) {
  const es = new EventSource(url);
  es.onopen = () => setConn("live");
  es.onerror = () => setConn("reconnecting");
  for (const [name, fn] of Object.entries(handlers)) {
    es.addEventListener(name, (ev) => fn(JSON.parse(ev.data)));
  }
  return es;
}

function header(doc) {
  document.getElementById("gw-name").textContent = doc.gateway + " " + doc.version;
  const nav = document.getElementById("nav-commission");
  if (nav) nav.hidden = !doc.writes;
  if (nav && !doc.writes) nav.remove();
}

// ------------------------------------------------------------------ overview + nodes
// Another master (NMT we did not send, our heartbeat COB-ID from elsewhere) or another SDO
// client: what was seen last and how often; "none seen" otherwise.
function peerFacts(seen, kind) {
  const entries = Object.entries(seen || {});
  if (!entries.length) return "none seen";
  return el("span", { class: "peers" }, ...entries.map(([k, v]) =>
    el("span", {}, badge(k, kind), ` ${v.detail} (${v.count}×) `)));
}

function busState(can) {
  return can.state === "ok" ? badge("ok", "good") : can.state === "error" ? badge("error", "stale") : badge(can.state || "down", "bad");
}

function busLoad(percent, bitrate) {
  return percent === null || percent === undefined
    ? "bit rate not configured" : `about ${percent} % of ${bitrate / 1000} kbit/s`;
}

// Several CAN networks (networks:): one card per network, its bus, load, peers and nodes.
function renderNetworks(o) {
  const nets = Object.entries(o.networks || {});
  const first = document.getElementById("ov-bus").closest("section");
  if (nets.length < 2) return false;
  let after = first;
  for (const [name, n] of nets) {
    let card = document.querySelector(`section[data-network="${CSS.escape(name)}"]`);
    if (!card) {
      card = el("section", { class: "card", "data-network": name, "aria-label": "CAN network " + name },
        el("h2", {}, `CAN network ${name} (net ${n.number})`), el("dl", { class: "facts" }));
      after.after(card);
    }
    after = card;
    const r = n.rates || {};
    setFacts(card.querySelector("dl"), [
      ["Interface", `${n.interface} ${n.channel}`],
      ["State", el("span", {}, busState(n), n.detail ? " " + n.detail : "")],
      ["Frames in", `${fmtNumber(r.frames_in || 0)} /s (${n.frames_in} total)`],
      ["Frames out", `${fmtNumber(r.frames_out || 0)} /s (${n.frames_out} total)`],
      ["Bus load", busLoad(n.bus_load_percent, n.bitrate)],
      ["Reopens", String(n.reopens || 0)],
      ["Other masters", peerFacts((n.peers || {}).other_master, "bad")],
      ["Pair", (n.pair || {}).role ? pairRole(n.pair.role) : "none"],
      ["Nodes", (n.nodes || []).join(", ") || "none"],
      ["Monitor", el("a", { href: "/monitor?network=" + encodeURIComponent(name) }, "bus monitor of " + name)],
    ]);
  }
  first.hidden = true;
  return true;
}

function renderOverview(o) {
  const can = o.can || {};
  const rates = o.rates || {};
  const state = busState(can);
  setFacts(document.getElementById("ov-gateway"), [
    ["Uptime", fmtUptime(o.uptime_s || 0)],
    ["Nodes", `${o.nodes_usable} of ${o.nodes} usable`],
    ["Threads", Object.keys(o.threads_failed || {}).length ? "failed: " + Object.keys(o.threads_failed).join(", ") : "all running"],
  ]);
  if (!renderNetworks(o)) setFacts(document.getElementById("ov-bus"), [
    ["Interface", `${can.interface} ${can.channel}`],
    ["State", el("span", {}, state, can.detail ? " " + can.detail : "")],
    ["Frames in", `${fmtNumber(rates.frames_in || 0)} /s (${o.frames_in} total)`],
    ["Frames out", `${fmtNumber(rates.frames_out || 0)} /s (${o.frames_out} total)`],
    ["Bus load", busLoad(o.bus_load_percent, o.bitrate)],
    ["Error frames", String(o.bus_errors)],
    ["Reopens", String(can.reopens || 0)],
    ["Undecodable", `${o.decode_errors} frames, ${o.unknown_cob_id} unknown COB-IDs`],
    ["Other masters", peerFacts((o.peers || {}).other_master, "bad")],
    ["Other SDO clients", peerFacts((o.peers || {}).other_sdo_clients, "info")],
    ["Unconfigured ids", ((o.peers || {}).unconfigured_node_ids || []).join(", ") || "none"],
  ]);
  const mb = o.modbus;
  setFacts(document.getElementById("ov-modbus"), mb ? [
    ["Listening", mb.listen + (mb.read_only ? " (read only)" : "")],
    ["Serving", mb.serving ? badge("yes", "good") : badge("no", "bad")],
    ["Clients", String(mb.clients)],
    ["Requests", `${fmtNumber(rates.modbus_requests || 0)} /s (${mb.requests} total)`],
    ["Exceptions", String(mb.exceptions)],
  ] : [["Modbus TCP", "disabled"]]);
  const z = o.zenoh;
  setFacts(document.getElementById("ov-zenoh"), z ? [
    ["Mode", z.mode],
    ["Session", z.up ? badge("open", "good") : badge("not open", "bad")],
    ["Routers", z.mode === "client" ? (z.routers ? badge(String(z.routers) + " connected", "good") : badge("none connected", "bad")) : String(z.routers)],
    ["Peers", String(z.peers)],
    ["Publications", `${fmtNumber(rates.zenoh_publications || 0)} /s (${z.publications} total)`],
    ["Key prefix", el("span", { class: "code" }, z.prefix)],
  ] : [["Zenoh", "disabled"]]);
  renderPair(o.pair || {});
}

// A hot-standby pair (master.redundancy): this gateway's role and what it heard of the other
// one; the card stays hidden outside a pair.
function pairRole(role) {
  return badge(role, role === "active" ? "good" : role === "unknown" ? "stale" : "info");
}

function renderPair(pair) {
  const card = document.getElementById("ov-pair-card");
  if (!card) return;
  card.hidden = !pair.role;
  if (!pair.role) return;
  const p = pair.peer || {};
  const who = p.node_id == null ? "" : ` node id ${p.node_id}` + (p.priority == null ? "" : `, priority ${p.priority}`);
  setFacts(document.getElementById("ov-pair"), [
    ["This gateway", pairRole(pair.role)],
    ["Other gateway", p.heard ? el("span", {}, pairRole(p.role), who) : el("span", {}, badge("not heard", "stale"), who)],
    ["Master id", pair.master_id == null ? "none heard" : String(pair.master_id)],
    ["Its claim", p.claim_age_s == null ? "never heard" : fmtAge(p.claim_age_s) + " ago"],
    ["Its heartbeat", p.heartbeat_age_s == null ? "never heard" : fmtAge(p.heartbeat_age_s) + " ago"],
  ]);
}

function presenceBadge(r) {
  return r.presence === "alive" ? badge("alive", "good") : badge(r.presence, r.presence === "lost" ? "bad" : "stale");
}

// The node's status (its worst process quality); a node whose PDOs map nothing says why it is bad.
function statusCell(r) {
  return r.quality_note ? el("span", {}, badge(r.quality), " " + r.quality_note) : badge(r.quality);
}

function linkBadge(word) {
  if (word === "ok") return badge("ok", "good");
  if (word === "fault") return badge("fault", "bad");
  if (word === "unknown") return badge("unknown", "stale");
  return el("span", { class: "muted" }, word);
}

function renderNodes(rows) {
  const tbody = document.querySelector("#nodes tbody");
  const seen = new Set();
  for (const r of rows) {
    seen.add(r.name);
    let tr = tbody.querySelector(`tr[data-node="${CSS.escape(r.name)}"]`);
    if (!tr) {
      tr = el("tr", { "data-node": r.name });
      tbody.append(tr);
    }
    const emcy = r.last_emcy ? el("span", {}, el("span", { class: "code" }, r.last_emcy.code), " " + r.last_emcy.text) : el("span", { class: "muted" }, "none");
    const on = document.querySelector("section[data-network]") ? el("span", { class: "muted" }, " on " + r.network) : "";
    const cells = [
      ["name", el("span", {}, el("a", { href: "/node/" + encodeURIComponent(r.name) }, r.name), on)],
      ["node_id", String(r.node_id), "num"],
      ["profile", el("span", { title: r.title }, r.profile)],
      ["quality", statusCell(r)],
      ["presence", presenceBadge(r)],
      ["nmt_state", r.nmt_state],
      ["lifecycle", r.outputs === "safe" ? el("span", {}, r.lifecycle + " ", badge("outputs: safe", "stale")) : r.lifecycle],
      ["supervision", r.supervision_timing],
      ["link", linkBadge(r.link)],
      ["last_emcy", emcy],
      ["boots", String(r.boots), "num"],
      ["losses", String(r.losses), "num"],
      ["data_age", fmtAge(r.data_age_s), "num"],
    ];
    tr.replaceChildren(...cells.map(([col, v, cls]) => el("td", { "data-col": col, class: cls || null }, v)));
  }
  for (const tr of [...tbody.querySelectorAll("tr")]) {
    if (!seen.has(tr.dataset.node)) tr.remove();
  }
}

async function initIndex() {
  const doc = await getJSON("/api/overview");
  header(doc);
  renderOverview(doc.overview);
  renderNodes(doc.nodes);
  liveStream("/api/stream", { overview: renderOverview, nodes: renderNodes });
}

// ------------------------------------------------------------------ node page
let nodeSignals = {};

function renderNodeRow(r) {
  document.getElementById("node-title").textContent = `Node ${r.name} (id ${r.node_id}, ${r.profile})`;
  document.title = `canopen-gateway: ${r.name}`;
  setFacts(document.getElementById("node-state"), [
    ["Status", statusCell(r)],
    ["Presence", presenceBadge(r)],
    ["NMT state", r.nmt_state],
    ["Lifecycle", r.lifecycle],
    ["Guarding-bit link", linkBadge(r.link)],
    ["Outputs", r.outputs === "safe" ? badge("outputs: safe", "stale") : "normal (as the last write set them)"],
    ["Data age", fmtAge(r.data_age_s)],
    ["Device", r.title],
  ]);
  setFacts(document.getElementById("node-counts"), [
    ["Supervision", r.supervision_timing],
    ["Boots", String(r.boots)],
    ["Losses", String(r.losses)],
    ["Link faults", String(r.link_faults)],
    ["EMCY received", String(r.emcy_count)],
    ["Last SDO abort", r.last_sdo_abort || "none"],
    ["Last problem", r.last_error || "none"],
  ]);
}

function renderEmcy(e) {
  const box = document.getElementById("node-errors");
  if (!e.current.length) {
    box.replaceChildren(el("p", {}, badge("no error active", "good")));
  } else {
    box.replaceChildren(el("ul", {}, ...e.current.map((c) => el("li", {}, badge("active", "bad"), " ", el("span", { class: "code" }, c.code), " " + c.text))));
  }
  const tbody = document.querySelector("#emcy tbody");
  tbody.replaceChildren(...(e.history.length ? e.history.map((h) => el("tr", {},
    el("td", {}, fmtTime(h.ts)), el("td", { class: "code" }, h.code), el("td", {}, h.text),
    el("td", { class: "code" }, h.register + (h.register_bits.length ? " (" + h.register_bits.join(", ") + ")" : "")),
    el("td", { class: "code" }, h.manufacturer))) : [el("tr", {}, el("td", { colSpan: 5, class: "muted" }, "no EMCY received since the gateway started"))]));
}

function valueText(sig, v) {
  if (v.value === null || v.value === undefined) {
    return v.quality === "on request" ? "read by SDO on request" : "no value yet";
  }
  let t = typeof v.value === "number" ? fmtNumber(v.value) : String(v.value);
  if (v.text) t += " (" + v.text + ")";
  if (v.bits) {
    const on = Object.entries(v.bits).filter(([, b]) => b === true).map(([n]) => n);
    if (on.length) t += " [" + on.join(", ") + "]";
  }
  return t;
}

function qualityCell(q) {
  if (q === "good" || q === "stale" || q === "bad") return badge(q);
  return el("span", { class: "muted" }, q);
}

// Text that may wrap after each `sep` and nowhere else (Zenoh keys after "/", signal names
// after "_"): the signals table fits 1280 px.
function breakable(text, sep = "/") {
  const out = [];
  text.split(sep).forEach((part, i) => { if (i) out.push(sep, document.createElement("wbr")); out.push(part); });
  return out;
}

function renderSignals(signals) {
  const tbody = document.querySelector("#signals tbody");
  tbody.replaceChildren();
  nodeSignals = {};
  for (const s of signals) {
    nodeSignals[s.name] = s;
    const tr = el("tr", { "data-signal": s.name },
      el("th", { scope: "row", title: s.description }, ...breakable(s.name, "_")),
      el("td", { "data-col": "value", class: "num" }, ""),
      el("td", { "data-col": "unit" }, s.unit),
      el("td", { "data-col": "quality" }, ""),
      el("td", { "data-col": "age", class: "num" }, ""),
      el("td", { "data-col": "source" }, s.source + (s.writable ? " (writable)" : "")),
      el("td", { "data-col": "object", class: "code" }, s.object),
      el("td", { "data-col": "modbus", class: "nowrap" }, s.modbus || el("span", { class: "muted" }, "not mapped")),
      el("td", { "data-col": "zenoh", class: "code" }, ...breakable(s.zenoh.join("\n"))));
    tbody.append(tr);
  }
}

function renderValues(values) {
  for (const [name, v] of Object.entries(values)) {
    const tr = document.querySelector(`#signals tr[data-signal="${CSS.escape(name)}"]`);
    if (!tr) continue;
    tr.querySelector('[data-col="value"]').textContent = valueText(nodeSignals[name], v);
    tr.querySelector('[data-col="quality"]').replaceChildren(qualityCell(v.quality));
    tr.querySelector('[data-col="age"]').textContent = v.quality === "output" || v.quality === "on request" ? "" : fmtAge(v.age_s);
  }
}

function renderRegisters(rows) {
  const tbody = document.querySelector("#registers tbody");
  tbody.replaceChildren(...rows.map((r) => el("tr", {},
    el("td", { class: "num" }, r.unit_id), el("td", {}, r.table), el("td", { class: "num" }, r.address),
    el("td", {}, r.type), el("td", {}, r.access), el("td", { class: "code" }, r.signal),
    el("td", {}, r.unit), el("td", {}, r.scaling), el("td", {}, r.description))));
}

async function initNode() {
  const name = decodeURIComponent(location.pathname.replace(/^\/node\//, ""));
  const [ov, doc] = await Promise.all([getJSON("/api/overview"), getJSON("/api/node/" + encodeURIComponent(name))]);
  header(ov);
  renderNodeRow(doc.row);
  renderSignals(doc.signals);
  renderValues(doc.values);
  renderEmcy(doc.emcy);
  renderRegisters(doc.registers);
  const es = liveStream("/api/stream?node=" + encodeURIComponent(name), {
    node: (d) => { renderNodeRow(d.row); renderEmcy(d.emcy); },
    values: renderValues,
  });
  await initNodeFirstHour(name, doc, es);
}

// ------------------------------------------------------------------ commissioning
const SDO_TYPES = ["", "bool", "int8", "uint8", "int16", "uint16", "int24", "uint24", "int32", "uint32", "int64", "uint64", "float32", "string", "bytes"];

async function commission(op, body) {
  const r = await fetch("/api/commission/" + op, {
    method: "POST",
    headers: { "Content-Type": "application/json", "Authorization": "Bearer " + (sessionStorage.getItem(TOKEN_KEY) || "") },
    body: JSON.stringify(body),
  });
  let doc;
  try { doc = await r.json(); } catch (e) { doc = { message: "HTTP " + r.status }; }
  return { ok: r.ok, status: r.status, doc };
}

function showResult(id, res) {
  const box = document.getElementById("result-" + id);
  box.className = "result " + (res.ok ? "ok" : "err");
  if (res.ok) {
    const d = res.doc;
    if (id === "sdo-read") box.textContent = `${d.node} ${d.object} = ${d.value}`;
    else if (id === "scan") box.textContent = d.report.join("\n");
    else if (id === "lss-inquire") box.textContent = ["vendor_id", "product_code", "revision", "serial", "node_id"].map((k) => `${k}: ${d[k]}`).join("\n");
    else if (id === "lss-fast-scan") box.textContent = d.found.map((f) => `found ${f.address}` + (f.node_id ? `: node id ${f.node_id}${f.stored ? ", stored" : ""}` : ""))
      .concat(d.failed ? [`then: ${d.failed}`] : [], [`${d.frames} frames on ${d.network}; ${d.note}`]).join("\n");
    else box.textContent = "done: " + JSON.stringify(d);
  } else {
    let t = `refused (HTTP ${res.status}): ${res.doc.message || ""}`;
    if (res.doc.abort_code && !t.includes(res.doc.abort_code)) t += `\nSDO abort ${res.doc.abort_code}: ${res.doc.abort_text}`;
    box.textContent = t;
    if (res.status === 401 || res.status === 403) showLocked("The token was refused; unlock again.");
  }
}

function showLocked(message) {
  document.getElementById("ops").hidden = true;
  const box = document.getElementById("result-login");
  box.className = "result " + (message ? "err" : "");
  box.textContent = message || "Locked.";
}

function formValues(form) {
  const out = {};
  for (const [k, v] of new FormData(form).entries()) if (v !== "") out[k] = v;
  return out;
}

function numberOrText(v) {
  const t = v.trim();
  if (/^[-+]?\d+$/.test(t)) return parseInt(t, 10);
  if (/^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$/.test(t)) return parseFloat(t);
  return t;
}

async function initCommission() {
  const ov = await getJSON("/api/overview");
  header(ov);
  const names = ov.nodes.map((r) => r.name);
  for (const sel of document.querySelectorAll(".node-select")) {
    const opts = (sel.dataset.all ? ["all"] : []).concat(names);
    sel.replaceChildren(...opts.map((n) => el("option", { value: n }, n)));
  }
  for (const sel of document.querySelectorAll(".type-select")) {
    sel.replaceChildren(...SDO_TYPES.map((t) => el("option", { value: t }, t || "from the EDS")));
  }
  const networks = Object.keys(ov.overview.networks || {}); // LSS and the scan: one bus each
  for (const sel of document.querySelectorAll(".network-select")) {
    sel.replaceChildren(...networks.map((n) => el("option", { value: n }, n)));
    sel.closest("label").hidden = networks.length < 2;
  }
  const details = {};
  async function loadSignals() {
    const node = document.getElementById("set-node").value;
    if (!node) return;
    details[node] = details[node] || await getJSON("/api/node/" + encodeURIComponent(node));
    const writable = details[node].signals.filter((s) => s.writable);
    const sel = document.getElementById("set-signal");
    sel.replaceChildren(...writable.map((s) => el("option", { value: s.name }, s.name + (s.unit ? " [" + s.unit + "]" : ""))));
    hint();
  }
  function hint() {
    const node = document.getElementById("set-node").value;
    const s = (details[node] ? details[node].signals : []).find((x) => x.name === document.getElementById("set-signal").value);
    document.getElementById("set-hint").textContent = s ? `${s.type} via ${s.source} ${s.object}` + (s.min !== null || s.max !== null ? `, range ${s.min ?? "-"} to ${s.max ?? "-"} ${s.unit}` : "") : "this node has no writable signal";
  }
  document.getElementById("set-node").addEventListener("change", loadSignals);
  document.getElementById("set-signal").addEventListener("change", hint);

  document.getElementById("form-login").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    sessionStorage.setItem(TOKEN_KEY, document.getElementById("token").value);
    const res = await commission("login", {});
    if (res.ok) {
      document.getElementById("ops").hidden = false;
      const box = document.getElementById("result-login");
      box.className = "result ok";
      box.textContent = "Unlocked.";
      document.getElementById("token").value = "";
      loadSignals();
    } else {
      sessionStorage.removeItem(TOKEN_KEY);
      showLocked(res.status === 403 ? "Wrong token." : res.doc.message);
    }
  });
  document.getElementById("lock").addEventListener("click", () => { sessionStorage.removeItem(TOKEN_KEY); showLocked(""); });

  const ops = { "sdo-read": (v) => v, "sdo-write": (v) => ({ ...v, value: v.type === "string" || v.type === "bytes" ? v.value : numberOrText(v.value || "") }),
    "nmt": (v) => v, "set": (v) => ({ ...v, value: numberOrText(v.value || "") }), "lss-inquire": (v) => v,
    "lss-fast-scan": (v) => ({ ...v, store: v.store === "true" }), "scan": (v) => v };
  for (const [op, shape] of Object.entries(ops)) {
    document.getElementById("form-" + op).addEventListener("submit", async (ev) => {
      ev.preventDefault();
      const box = document.getElementById("result-" + op);
      box.className = "result";
      box.textContent = "working";
      showResult(op, await commission(op, shape(formValues(ev.target))));
    });
  }
  if (sessionStorage.getItem(TOKEN_KEY)) {
    const res = await commission("login", {});
    if (res.ok) { document.getElementById("ops").hidden = false; loadSignals(); }
  }
  setConn("");
}

// ------------------------------------------------------------------ node page: trends, read, faults
// Trends: samples come from the gateway (GET /api/trend/<node>, then "trend" events on the node's
// stream once a second). Each sample has a quality: good values are drawn solid, stale ones
// (last known value) grey and dashed, bad ones not at all (a gap).
const QUALITY_WORDS = ["good", "stale", "bad"];
const trendCharts = {}; // signal name -> { plot, t, good, stale, quality, unit, box }
let trendWindowS = 300;

// the widest time label ("00:00:00", about 50 px in the axis font) and a gap a reader sees
const TREND_TICK_SPACE_PX = 60;
// the steps between time labels, in seconds (uPlot's own skip from 1 to 5 minutes, which leaves
// a 5-minute trend with one label)
const TREND_TICK_INCRS_S = [1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600];

function clockLabel(t, withSeconds) {
  const d = new Date(t * 1000), two = (n) => String(n).padStart(2, "0");
  return two(d.getHours()) + ":" + two(d.getMinutes()) + (withSeconds ? ":" + two(d.getSeconds()) : "");
}

function trendSize(box) {
  return { width: Math.max(240, box.clientWidth - 4), height: 150 };
}

function trendLast(c) {
  const n = c.t.length;
  if (!n) return "no sample yet";
  const q = QUALITY_WORDS[c.quality[n - 1]];
  const v = q === "good" ? c.good[n - 1] : q === "stale" ? c.stale[n - 1] : null;
  return (v === null ? "no valid value" : fmtNumber(v) + (c.unit ? " " + c.unit : "")) + " (" + q + ")";
}

function buildTrends(doc) {
  const box = document.getElementById("trends");
  box.replaceChildren();
  if (!doc.signals.length) {
    box.append(el("p", { class: "muted" }, "This node has no numeric process value to plot."));
    return;
  }
  trendWindowS = doc.window_s || trendWindowS;
  for (const s of doc.signals) {
    const last = el("span", { class: "trend-last", "data-col": "last" }, "");
    const plotBox = el("div", { class: "trend-plot" });
    const fig = el("figure", { class: "trend", "data-signal": s.name },
      el("figcaption", {}, el("span", { class: "code" }, s.name), s.unit ? " [" + s.unit + "]" : "", " ", last),
      plotBox);
    box.append(fig);
    const c = { t: [], good: [], stale: [], quality: [], unit: s.unit, last, plot: null, box: plotBox };
    const size = trendSize(plotBox);
    c.plot = new uPlot({
      width: size.width, height: size.height, legend: { show: false },
      cursor: { drag: { x: false, y: false } },
      scales: { x: { time: true } },
      // time labels on one line, 24 h ("21:05", "21:05:30" under a minute apart), at least
      // TREND_TICK_SPACE_PX apart: uPlot's own two-line labels (time, then date) collide
      axes: [{ stroke: "#4d5560", space: TREND_TICK_SPACE_PX, incrs: TREND_TICK_INCRS_S,
               values: (u, splits, ax, space, incr) => splits.map((t) => clockLabel(t, incr < 60)) },
             { stroke: "#4d5560", size: 60 }],
      series: [{}, { label: "good", stroke: "#0a57a4", width: 2, spanGaps: false },
        { label: "stale", stroke: "#6b7580", width: 2, dash: [6, 4], spanGaps: false }],
    }, [c.t, c.good, c.stale], plotBox);
    trendCharts[s.name] = c;
  }
}

function addTrend(doc) {
  doc.signals.forEach((s, i) => {
    const c = trendCharts[s.name];
    if (!c) return;
    const lastT = c.t.length ? c.t[c.t.length - 1] : -Infinity;
    doc.t.forEach((t, k) => {
      if (t <= lastT) return; // already shown (the stream's first update repeats the ring)
      const v = doc.values[i][k], q = doc.quality[i][k];
      c.t.push(t);
      c.quality.push(q);
      c.good.push(q === 0 ? v : null);
      c.stale.push(q === 1 ? v : null);
    });
    const oldest = (doc.t.length ? doc.t[doc.t.length - 1] : Date.now() / 1000) - trendWindowS;
    let drop = 0;
    while (drop < c.t.length && c.t[drop] < oldest) drop++;
    if (drop) for (const a of [c.t, c.good, c.stale, c.quality]) a.splice(0, drop);
    c.plot.setData([c.t, c.good, c.stale]);
    c.last.textContent = trendLast(c);
  });
}

// Read buttons: configuration objects (source SDO) are read on request, through the gateway's
// command service. The result stays in the value cell until the next read.
const readResults = {};

function showReads() {
  for (const [name, text] of Object.entries(readResults)) {
    const td = document.querySelector(`#signals tr[data-signal="${CSS.escape(name)}"] [data-col="value"]`);
    if (td) td.textContent = text;
  }
}

function addReadButtons(node) {
  for (const [name, s] of Object.entries(nodeSignals)) {
    if (s.source !== "SDO" || s.access === "wo") continue;
    const td = document.querySelector(`#signals tr[data-signal="${CSS.escape(name)}"] [data-col="source"]`);
    if (!td || td.querySelector("button")) continue;
    const b = el("button", { type: "button", class: "read secondary", "data-read": name, title: "read " + s.object + " by SDO now" }, "Read");
    b.setAttribute("aria-label", "Read " + name);
    b.addEventListener("click", () => readObject(node, name, b));
    td.append(" ", b);
  }
}

async function readObject(node, name, button) {
  button.disabled = true;
  try {
    const r = await operatorFetch(`/api/read/${encodeURIComponent(node)}/${encodeURIComponent(name)}`, {
      method: "POST", headers: { "Content-Type": "application/json" }, body: "{}",
    });
    let d;
    try { d = await r.json(); } catch (e) { d = { message: "HTTP " + r.status }; }
    if (r.ok) {
      let t = (typeof d.value === "number" ? fmtNumber(d.value) : String(d.value)) + (d.unit ? " " + d.unit : "");
      if (d.text) t += " (" + d.text + ")";
      readResults[name] = t + " — read " + fmtTime(d.ts).split(" ").pop();
    } else if (d.abort_code) {
      readResults[name] = `SDO abort ${d.abort_code}: ${d.abort_text}`;
    } else if (r.status === 429) {
      readResults[name] = "too many reads: " + d.message;
    } else {
      readResults[name] = `not read (HTTP ${r.status}): ${d.message || ""}`;
    }
  } finally {
    button.disabled = false;
  }
  showReads();
}

// Simulated faults (nodes simulated inside the gateway only; see GET /api/sim for the rule).
async function initFaults(node) {
  let sim;
  try { sim = await getJSON("/api/sim"); } catch (e) { return; }
  if (!sim.nodes || !sim.nodes[node]) return;
  const sec = document.getElementById("sec-faults");
  sec.hidden = false;
  document.getElementById("fault-rule").textContent = "This node is simulated by the gateway: these buttons change what the simulated device does (" + sim.rule_text + "). Watch Modbus, Zenoh and this page follow.";
  const box = document.getElementById("fault-buttons");
  const result = document.getElementById("fault-result");
  const show = (state) => {
    box.dataset.unplugged = state.unplugged;
    const words = [state.unplugged ? "unplugged" : "plugged in", state.heartbeat ? "heartbeat on" : "heartbeat off", state.emcy ? "EMCY " + state.emcy + " raised" : "no EMCY raised"];
    document.getElementById("fault-state").textContent = "Simulated device: " + words.join(", ") + ".";
  };
  box.replaceChildren(el("p", { id: "fault-state" }, ""));
  for (const [action, text] of Object.entries(sim.actions)) {
    const b = el("button", { type: "button", class: "secondary", "data-fault": action, title: text }, action);
    b.addEventListener("click", async () => {
      const headers = { "Content-Type": "application/json", "X-Canopen-Client": "console" };
      const r = await operatorFetch(`/api/sim/${encodeURIComponent(node)}/${action}`, { method: "POST", headers, body: "{}" });
      let d;
      try { d = await r.json(); } catch (e) { d = { message: "HTTP " + r.status }; }
      result.className = "result " + (r.ok ? "ok" : "err");
      result.textContent = r.ok ? `${action}: done: ${text}` : `refused (HTTP ${r.status}): ${d.message || ""}`;
      if (r.ok) show(d.state);
    });
    box.append(b);
  }
  show(sim.nodes[node]);
}

async function initNodeFirstHour(name, doc, es) {
  // trends and faults come before the signals table on the page
  const signals = document.querySelector('section[aria-labelledby="h-signals"]');
  signals.before(document.getElementById("sec-faults"), document.getElementById("sec-trends"));
  addReadButtons(name);
  es.addEventListener("values", showReads);
  const trend = await getJSON("/api/trend/" + encodeURIComponent(name));
  buildTrends(trend);
  addTrend(trend);
  es.addEventListener("trend", (ev) => addTrend(JSON.parse(ev.data)));
  window.addEventListener("resize", () => {
    for (const c of Object.values(trendCharts)) c.plot.setSize(trendSize(c.box));
  });
  await initFaults(name);
}

// ------------------------------------------------------------------ events page
const events = []; // newest last; bounded like the gateway's ring
const MAX_EVENTS_SHOWN = 500;

function eventFilter() {
  const node = document.getElementById("ev-node").value;
  const kinds = new Set([...document.querySelectorAll('input[name="kind"]:checked')].map((i) => i.value));
  return (e) => (!node || e.node === node) && kinds.has(e.kind);
}

const KIND_BADGE = { emcy: ["EMCY", "bad"], state: ["state", "info"], warning: ["warning", "stale"], error: ["error", "bad"] };

function renderEvents() {
  const keep = eventFilter();
  const shown = events.filter(keep).reverse();
  const tbody = document.querySelector("#events tbody");
  tbody.replaceChildren(...(shown.length ? shown.map((e) => el("tr", { "data-kind": e.kind, "data-seq": String(e.seq) },
    el("td", { class: "nowrap" }, fmtTime(e.ts)),
    el("td", {}, badge(...(KIND_BADGE[e.kind] || [e.kind, "info"]))),
    el("td", {}, e.node ? el("a", { href: "/node/" + encodeURIComponent(e.node) }, e.node) : el("span", { class: "muted" }, "gateway")),
    el("td", { class: "event-text" }, e.text))) : [el("tr", {}, el("td", { colSpan: 4, class: "muted" }, "no event of these kinds yet"))]));
  document.getElementById("ev-count").textContent = `${shown.length} of ${events.length} events shown`;
}

function addEvents(list) {
  const last = events.length ? events[events.length - 1].seq : 0;
  for (const e of list) if (e.seq > last) events.push(e);
  if (events.length > MAX_EVENTS_SHOWN) events.splice(0, events.length - MAX_EVENTS_SHOWN);
  renderEvents();
}

async function initEvents() {
  const [ov, doc] = await Promise.all([getJSON("/api/overview"), getJSON("/api/events")]);
  header(ov);
  const sel = document.getElementById("ev-node");
  const wanted = new URLSearchParams(location.search).get("node");
  for (const r of ov.nodes) sel.append(el("option", { value: r.name, selected: r.name === wanted }, r.name));
  sel.addEventListener("change", renderEvents);
  for (const i of document.querySelectorAll('input[name="kind"]')) i.addEventListener("change", renderEvents);
  addEvents(doc.events);
  liveStream("/api/stream", { events: (d) => addEvents(d.events) });
  const form = document.getElementById("journal-form");
  form.addEventListener("submit", (ev) => { ev.preventDefault(); loadJournal(); });
  sel.addEventListener("change", loadJournal);
  loadJournal();
}

// The journal's entries of a range (GET /api/journal), and the CSV link of the same range.
function journalQuery() {
  const q = new URLSearchParams();
  q.set("from", document.getElementById("jr-from").value.trim());
  const to = document.getElementById("jr-to").value.trim();
  if (to) q.set("to", to);
  const node = document.getElementById("ev-node").value;
  if (node) q.set("node", node);
  q.set("kind", [...document.querySelectorAll('input[name="jkind"]:checked')].map((i) => i.value).join(",") || "none");
  return q.toString();
}

// Answers may come back out of order (the page's first load, then a submit): only the answer
// of the latest request is shown, and the table says which query it shows (data-query).
let journalRequests = 0;

async function loadJournal() {
  const q = journalQuery();
  const mine = ++journalRequests;
  document.getElementById("jr-csv").href = "/api/journal.csv?" + q;
  const status = document.getElementById("jr-status");
  const r = await operatorFetch("/api/journal?" + q, { cache: "no-store" });
  const doc = await r.json();
  if (mine !== journalRequests) return; // a later request's answer is the one shown
  const table = document.getElementById("journal");
  const tbody = table.querySelector("tbody");
  table.dataset.query = q;
  if (!r.ok) {
    status.textContent = doc.message || r.statusText;
    tbody.replaceChildren();
    return;
  }
  status.textContent = `${doc.entries.length} entries` + (doc.truncated ? " (the first ones of the range: narrow it or export CSV)" : "");
  tbody.replaceChildren(...doc.entries.map((e) => el("tr", { "data-kind": e.kind },
    el("td", { class: "nowrap" }, fmtTime(e.ts)),
    el("td", {}, badge(...(KIND_BADGE[e.kind] || [e.kind, "info"]))),
    el("td", {}, e.node || ""),
    el("td", {}, e.seq == null ? "" : String(e.seq)),
    el("td", { class: "event-text" }, e.text))));
}

// ------------------------------------------------------------------ bus monitor
// The gateway filters by node and kind and sends at most `max_lines_per_s` lines a second; the
// page keeps the last MAX_FRAME_ROWS rows. Pause closes the stream (the gateway stops tapping
// its reader when no monitor page is open) and says what was not recorded.
const MAX_FRAME_ROWS = 500;
const mon = { es: null, paused: false, pausedAt: null, limit: 200 };

function fmtClock(ts) {
  const d = new Date(ts * 1000);
  return d.toLocaleTimeString(undefined, { hour12: false }) + "." + String(d.getMilliseconds()).padStart(3, "0");
}

function monitorQuery() {
  const node = document.getElementById("mon-node").value;
  const all = [...document.querySelectorAll('input[name="mkind"]')];
  const kinds = all.filter((i) => i.checked).map((i) => i.value);
  const q = new URLSearchParams();
  const net = document.getElementById("mon-network");
  if (net && net.value && !net.closest("label").hidden) q.set("network", net.value);
  if (node) q.set("node", node);
  if (kinds.length < all.length) q.set("kind", kinds.join(","));
  return { q, node, kinds: new Set(kinds) };
}

function monitorNote(text) {
  return el("tr", { class: "note" }, el("td", { colSpan: 6, class: "muted" }, text));
}

function skipText(n) {
  return `${n} frame${n === 1 ? "" : "s"} not shown (more than ${mon.limit} lines a second)`;
}

function addFrameRows(items) {
  const tbody = document.querySelector("#frames tbody");
  const { node, kinds } = monitorQuery();
  for (const f of items) {
    if (f.skipped !== undefined) {
      const top = tbody.firstElementChild;
      if (top && top.dataset.skipped) { // one note for the frames skipped in a row
        top.dataset.skipped = String(Number(top.dataset.skipped) + f.skipped);
        top.cells[0].textContent = skipText(Number(top.dataset.skipped));
      } else {
        const note = monitorNote(skipText(f.skipped));
        note.dataset.skipped = String(f.skipped);
        tbody.prepend(note);
      }
      continue;
    }
    const tr = el("tr", { "data-kind": f.kind, "data-node": f.node || "" },
      el("td", { class: "nowrap num" }, fmtClock(f.ts)),
      el("td", { class: "code" }, f.cob_id),
      el("td", {}, f.node ? el("a", { href: "/node/" + encodeURIComponent(f.node) }, f.node) : el("span", { class: "muted" }, f.node_id ? "id " + f.node_id : "-")),
      el("td", { class: "nowrap" }, f.service),
      el("td", { class: "frame-text" }, f.text),
      el("td", { class: "code frame-data" }, f.data));
    tr.hidden = (node && f.node !== node) || !kinds.has(f.kind);
    tbody.prepend(tr);
  }
  while (tbody.rows.length > MAX_FRAME_ROWS) tbody.lastElementChild.remove();
}

function monitorStatus(s) {
  const parts = [`${s.shown} shown`, `${s.skipped} skipped (over ${s.max_lines_per_s} lines a second)`];
  if (s.dropped) parts.push(`${s.dropped} not read by this page in time`);
  if (s.lost) parts.push(`${s.lost} lost in the gateway (its hand-off was full)`);
  document.getElementById("mon-status").textContent = parts.join(", ");
}

function monitorOpen() {
  if (mon.es) mon.es.close();
  const { q, kinds } = monitorQuery();
  if (!kinds.size) {
    mon.es = null;
    setConn("no kind selected");
    return;
  }
  const qs = q.toString();
  mon.es = liveStream("/api/monitor/stream" + (qs ? "?" + qs : ""), {
    hello: (h) => { mon.limit = h.max_lines_per_s; document.getElementById("mon-limit").textContent = String(h.max_lines_per_s); },
    frames: addFrameRows,
    status: monitorStatus,
  });
}

function monitorRefilter() {
  const { node, kinds } = monitorQuery();
  for (const tr of document.querySelectorAll("#frames tbody tr[data-kind]")) {
    tr.hidden = (node && tr.dataset.node !== node) || !kinds.has(tr.dataset.kind);
  }
  if (!mon.paused) monitorOpen();
}

function monitorPause() {
  const b = document.getElementById("mon-pause");
  const tbody = document.querySelector("#frames tbody");
  if (!mon.paused) {
    mon.paused = true;
    mon.pausedAt = Date.now() / 1000;
    if (mon.es) mon.es.close();
    mon.es = null;
    setConn("paused");
    b.textContent = "Resume";
    b.setAttribute("aria-pressed", "true");
  } else {
    mon.paused = false;
    tbody.prepend(monitorNote(`paused from ${fmtClock(mon.pausedAt)} to ${fmtClock(Date.now() / 1000)}: frames of that time not recorded`));
    b.textContent = "Pause";
    b.setAttribute("aria-pressed", "false");
    monitorOpen();
  }
}

async function initMonitor() {
  const ov = await getJSON("/api/overview");
  header(ov);
  const sel = document.getElementById("mon-node");
  const params = new URLSearchParams(location.search);
  const wanted = params.get("node");
  const networks = Object.keys(ov.overview.networks || {});
  const netSel = document.getElementById("mon-network");
  const byName = Object.fromEntries(ov.nodes.map((r) => [r.name, r]));
  const net0 = params.get("network") || (wanted && byName[wanted] ? byName[wanted].network : networks[0]);
  for (const n of networks) netSel.append(el("option", { value: n, selected: n === net0 }, n));
  netSel.closest("label").hidden = networks.length < 2; // a page watches one network's bus
  const fillNodes = () => {
    sel.replaceChildren(el("option", { value: "" }, "all nodes"));
    for (const r of ov.nodes.filter((r) => networks.length < 2 || r.network === netSel.value)) {
      sel.append(el("option", { value: r.name, selected: r.name === wanted }, `${r.name} (id ${r.node_id})`));
    }
  };
  const recNet = document.getElementById("rec-network"); // the recording is of the network shown
  fillNodes();
  recNet.value = netSel.value;
  netSel.addEventListener("change", () => { fillNodes(); recNet.value = netSel.value; document.querySelector("#frames tbody").replaceChildren(); monitorRefilter(); });
  sel.addEventListener("change", monitorRefilter);
  for (const i of document.querySelectorAll('input[name="mkind"]')) i.addEventListener("change", monitorRefilter);
  document.getElementById("mon-pause").addEventListener("click", monitorPause);
  document.getElementById("mon-clear").addEventListener("click", () => document.querySelector("#frames tbody").replaceChildren());
  if (!await unlockOperator()) {
    const r = await fetch("/api/monitor/stream", { method: "HEAD" });
    document.getElementById("mon-status").textContent = r.ok ? "" : "The bus monitor is for operators: " +
      (r.status === 403 ? "without web.token it is served to the gateway's own machine only." : "the token was not given.");
    setConn("locked");
    return;
  }
  monitorOpen();
}

// ------------------------------------------------------------------ not found (a node page of no node)
async function initNotFound() {
  const ov = await getJSON("/api/overview");
  header(ov);
  const asked = decodeURIComponent(location.pathname.replace(/^\/node\//, ""));
  if (location.pathname.startsWith("/node/")) document.getElementById("nf-what").textContent = `No node named “${asked}” is configured on this gateway.`;
  document.getElementById("nf-nodes").replaceChildren(...ov.nodes.map((r) =>
    el("li", {}, el("a", { href: "/node/" + encodeURIComponent(r.name) }, r.name), ` (id ${r.node_id}, ${r.profile})`)));
}

// ------------------------------------------------------------------ start
const INIT = { index: initIndex, node: initNode, commission: initCommission, events: initEvents, monitor: initMonitor, notfound: initNotFound };
INIT[page]().catch((err) => {
  setConn("error");
  const main = document.querySelector("main");
  main.prepend(el("p", { class: "banner bad", role: "alert" }, "The console could not load: " + err.message));
});
