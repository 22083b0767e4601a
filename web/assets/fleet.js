/* The fleet page: every device by line, live through server-sent events, filtered by state and line.
   Fast for 1000 devices: the rows are built as one HTML string (one parse, one layout), off-screen lines are not
   laid out (content-visibility in app.css), and updates are applied once per animation frame, writing only the
   cells whose text changed. */
"use strict";
(() => {
  const rows = new Map(); // name -> {data, tr, line, hidden, shown: {cell: text last written}}
  const lines = new Map(); // name -> {data, section, util, meter, pct, count}
  const pending = new Map(); // name -> the newest row not yet painted
  const COLUMNS = [["device"], ["model", "hide-narrow"], ["state"], ["fault"], ["currents"], ["last_poll"]];
  const ROW_PX = 32, LINE_PX = 72; // a line's height until it has been laid out once (content-visibility)
  let offset = 0; // server clock - this clock, s
  let built = false, frame = 0, pendingLines = null;

  const ESC = { "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" };
  function esc(s) { s = String(s); return /[&<>"']/.test(s) ? s.replace(/[&<>"']/g, (c) => ESC[c]) : s; }
  let words = { lang: null }; // the texts every row uses, in the page's language
  function texts() {
    if (words.lang !== SB.lang) {
      const [before, after] = SB.t("ago").split("{t}");
      words = { lang: SB.lang, before, after, offline: SB.t("offline_for") + " ", badges: {} };
      for (const s of Object.keys(SB.STATES)) {
        words.badges[s] = '<span class="state s-' + s + '" data-mark="' + esc(SB.STATES[s][2]) + '" data-state="' + s +
          '">' + esc(SB.stateText(s)) + "</span>";
      }
    }
    return words;
  }

  function fmtCurrents(c) {
    const parts = [];
    for (const k of ["a", "b", "c"]) if (c && c[k] != null) parts.push(k.toUpperCase() + "\u00a0" + Number(c[k]).toFixed(1));
    return parts.length ? parts.join(" · ") + "\u00a0A" : "–"; // a narrow screen wraps between phases only
  }
  function ageText(d) {
    const now = Date.now() / 1000 + offset, w = texts();
    if (d.online === false && d.offline_since != null) return w.offline + SB.age(now - d.offline_since);
    return d.time != null ? w.before + SB.age(now - d.time) + w.after : "–";
  }
  function faultText(d) { return d.fault ? d.fault.code + ": " + SB.label(d.fault) : ""; }
  function stateOf(d) { return SB.STATES[d.state] ? d.state : "unknown"; }

  function rowHTML(d) {
    const name = esc(d.name);
    return '<tr data-device="' + name + '" data-state="' + esc(d.state) + '"><th scope="row"><a href="/device/' +
      esc(encodeURIComponent(d.name)) + '">' + name + '</a></th><td class="hide-narrow">' + esc(d.model) +
      "</td><td>" + texts().badges[stateOf(d)] + '</td><td class="fault">' + esc(faultText(d)) + '</td><td class="num cur">' +
      esc(fmtCurrents(d.currents)) + '</td><td class="num">' + esc(ageText(d)) + "</td></tr>";
  }
  function lineHTML(l, devices) {
    const head = COLUMNS.map(([key, cls]) => '<th scope="col" data-i18n="' + key + '" class="c-' + key +
      (cls ? " " + cls : "") + '">' + esc(SB.t(key)) + "</th>").join("");
    return '<section class="line" data-line="' + esc(l.name) + '" aria-label="' + esc(l.name) + '"><h2><span>' +
      esc(l.name + " (" + l.transport + ")") + '</span><span class="util"></span></h2><div class="scroll">' +
      '<table class="fleet"><thead><tr>' + head + "</tr></thead><tbody>" + devices.map(rowHTML).join("") +
      "</tbody></table></div></section>";
  }

  function build(snapshot) {
    offset = snapshot.now - Date.now() / 1000;
    pending.clear(); pendingLines = null; // older than the snapshot
    const byLine = new Map(snapshot.lines.map((l) => [l.name, []]));
    for (const d of snapshot.devices) if (byLine.has(d.line)) byLine.get(d.line).push(d);
    const root = document.getElementById("lines");
    root.innerHTML = snapshot.lines.map((l) => lineHTML(l, byLine.get(l.name))).join(""); // one parse, one layout
    rows.clear(); lines.clear();
    snapshot.lines.forEach((l, i) => {
      const section = root.children[i];
      const line = { data: l, section, util: section.querySelector(".util"), pct: null, count: -1 };
      lines.set(l.name, line);
      const trs = section.querySelector("tbody").rows, devices = byLine.get(l.name);
      for (let k = 0; k < devices.length; k++) {
        const d = devices[k];
        rows.set(d.name, { data: d, tr: trs[k], line: l.name, hidden: false, shown: {} });
      }
    });
    paintLines(snapshot.lines);
    fillFilters();
    applyFilters();
    built = true;
    document.body.dataset.ready = "1";
  }

  function setCell(r, i, text) {
    if (r.shown[i] !== text) { r.tr.cells[i].textContent = text; r.shown[i] = text; }
  }
  function paint(r) {
    const d = r.data, s = stateOf(d), key = s + "/" + SB.lang;
    if (r.shown.state !== key) {
      SB.stateBadge(r.tr.cells[2].firstElementChild, s);
      r.tr.dataset.state = d.state;
      r.shown.state = key;
    }
    setCell(r, 3, faultText(d));
    setCell(r, 4, fmtCurrents(d.currents));
    setCell(r, 5, ageText(d));
  }
  function paintLines(list) {
    for (const l of list) {
      const line = lines.get(l.name);
      if (!line) continue;
      line.data = l;
      const u = l.utilisation;
      const pct = u == null ? "–" : (100 * u).toFixed(1) + " %";
      if (line.pct === pct + SB.lang) continue;
      line.pct = pct + SB.lang;
      const meter = SB.el("span", { class: "meter", role: "img", "aria-label": SB.t("utilisation") + " " + pct });
      const bar = SB.el("span", {});
      bar.style.width = Math.min(100, 100 * (u || 0)) + "%";
      meter.append(bar);
      line.util.replaceChildren(SB.t("utilisation") + " " + pct + " ", meter, " · " + l.devices + " " + SB.t("devices"));
    }
  }

  function fillFilters() {
    const st = document.getElementById("filter-state"), ln = document.getElementById("filter-line");
    const keepS = st.value, keepL = ln.value;
    st.replaceChildren(SB.el("option", { value: "", text: SB.t("all") }));
    for (const s of Object.keys(SB.STATES)) st.append(SB.el("option", { value: s, text: SB.stateText(s) }));
    ln.replaceChildren(SB.el("option", { value: "", text: SB.t("all") }));
    for (const name of lines.keys()) ln.append(SB.el("option", { value: name, text: name }));
    st.value = keepS; ln.value = keepL;
  }
  function applyFilters() {
    const st = document.getElementById("filter-state").value;
    const ln = document.getElementById("filter-line").value;
    const text = document.getElementById("filter-name").value.trim().toLowerCase();
    let shown = 0, online = 0, faults = 0;
    const perLine = new Map();
    for (const r of rows.values()) {
      const d = r.data;
      const show = (!st || d.state === st) && (!ln || d.line === ln) && (!text || d.name.toLowerCase().includes(text));
      if (r.hidden === show) { r.tr.hidden = !show; r.hidden = !show; }
      if (show) { shown++; perLine.set(r.line, (perLine.get(r.line) || 0) + 1); }
      if (d.online) online++;
      if (d.state === "fault") faults++;
    }
    for (const [name, line] of lines) {
      const count = perLine.get(name) || 0;
      if (count === line.count) continue;
      line.count = count;
      line.section.hidden = count === 0;
      line.section.style.containIntrinsicHeight = "auto " + (LINE_PX + ROW_PX * count) + "px";
    }
    document.getElementById("summary").textContent =
      SB.t("devices_shown", { shown, total: rows.size, online, faults });
  }

  function update(msg) {
    offset = msg.now - Date.now() / 1000;
    for (const d of msg.devices) pending.set(d.name, d);
    pendingLines = msg.lines;
    if (!frame) frame = requestAnimationFrame(applyPending); // a hidden tab keeps only the newest row per device
  }
  function applyPending() {
    frame = 0;
    if (!built) return;
    const announce = [];
    let refilter = false;
    for (const d of pending.values()) {
      const r = rows.get(d.name);
      if (!r) continue;
      if (r.data.state !== d.state) {
        announce.push(d.name + ": " + SB.stateText(d.state) + (d.fault ? " " + faultText(d) : ""));
        refilter = true;
      }
      if (r.data.online !== d.online) refilter = true;
      r.data = d;
      paint(r);
    }
    pending.clear();
    if (pendingLines) paintLines(pendingLines);
    pendingLines = null;
    if (refilter) applyFilters();
    if (announce.length) document.getElementById("announce").textContent = announce.slice(0, 5).join("; ");
  }
  function tick() { // the ages move on between updates
    for (const r of rows.values()) if (!r.hidden) setCell(r, 5, ageText(r.data));
  }

  // the snapshot, preloaded by fleet.html while the scripts load; the stream then carries only what changes
  const first = fetch("/api/fleet", { credentials: "same-origin" }).then((r) => (r.ok ? r.json() : null)).catch(() => null);

  document.addEventListener("DOMContentLoaded", () => {
    for (const id of ["filter-state", "filter-line", "filter-name"]) {
      document.getElementById(id).addEventListener("input", applyFilters);
    }
    document.getElementById("filters").addEventListener("submit", (e) => e.preventDefault());
    first.then((snapshot) => {
      if (snapshot && !built) build(snapshot);
      SB.stream(build, update, snapshot ? "/api/stream?after=" + encodeURIComponent(snapshot.id) : undefined);
    });
    setInterval(() => requestAnimationFrame(tick), 1000);
    SB.langListeners.push(() => {
      for (const r of rows.values()) paint(r);
      for (const th of document.querySelectorAll("#lines th[data-i18n]")) th.textContent = SB.t(th.dataset.i18n);
      paintLines([...lines.values()].map((l) => l.data));
      fillFilters(); applyFilters();
    });
  });
})();
