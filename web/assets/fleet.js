/* The fleet page: every device by line, live through server-sent events, filtered by state and line. */
"use strict";
(() => {
  const rows = new Map(); // name -> {data, tr, cells}
  const lines = new Map(); // name -> {data, section, util}
  let offset = 0; // server clock - this clock, s
  let built = false;

  function fmtCurrents(c) {
    const parts = [];
    for (const k of ["a", "b", "c"]) if (c && c[k] != null) parts.push(k.toUpperCase() + " " + Number(c[k]).toFixed(1));
    return parts.length ? parts.join(" · ") + " A" : "–";
  }
  function ageText(d) {
    const now = Date.now() / 1000 + offset;
    if (d.online === false && d.offline_since != null) return SB.t("offline_for") + " " + SB.age(now - d.offline_since);
    return d.time != null ? SB.t("ago", { t: SB.age(now - d.time) }) : "–";
  }
  function faultText(d) { return d.fault ? d.fault.code + ": " + SB.label(d.fault) : ""; }

  function makeRow(d) {
    const tr = SB.el("tr", { "data-device": d.name });
    const link = SB.el("a", { href: "/device/" + encodeURIComponent(d.name), text: d.name });
    const badge = SB.el("span", {});
    const cells = {
      state: badge, fault: SB.el("td", { class: "fault" }), currents: SB.el("td", { class: "num" }),
      age: SB.el("td", { class: "num" }),
    };
    tr.append(SB.el("th", { scope: "row" }, link), SB.el("td", { class: "hide-narrow", text: d.model }),
      SB.el("td", {}, badge), cells.fault, cells.currents, cells.age);
    return { data: d, tr, cells };
  }
  function paint(r) {
    const d = r.data;
    SB.stateBadge(r.cells.state, d.state);
    r.tr.dataset.state = d.state;
    r.cells.fault.textContent = faultText(d);
    r.cells.currents.textContent = fmtCurrents(d.currents);
    r.cells.age.textContent = ageText(d);
  }

  function build(snapshot) {
    const root = document.getElementById("lines");
    const fragment = document.createDocumentFragment(); // built detached, attached once: one layout
    rows.clear(); lines.clear();
    for (const l of snapshot.lines) {
      const util = SB.el("span", { class: "util" });
      const table = SB.el("table", {});
      const head = SB.el("tr", {});
      for (const [key, cls] of [["device"], ["model", "hide-narrow"], ["state"], ["fault"], ["currents"], ["last_poll"]]) {
        head.append(SB.el("th", { scope: "col", "data-i18n": key, class: cls || "", text: SB.t(key) }));
      }
      table.append(SB.el("thead", {}, head), SB.el("tbody", {}));
      const section = SB.el("section", { class: "line", "data-line": l.name, "aria-label": l.name },
        SB.el("h2", {}, SB.el("span", { text: l.name + " (" + l.transport + ")" }), util), SB.el("div", { class: "scroll" }, table));
      fragment.append(section);
      lines.set(l.name, { data: l, section, util, tbody: table.tBodies[0] });
    }
    for (const d of snapshot.devices) {
      const r = makeRow(d);
      rows.set(d.name, r);
      const line = lines.get(d.line);
      if (line) line.tbody.append(r.tr);
      paint(r);
    }
    paintLines(snapshot.lines);
    root.replaceChildren(fragment);
    fillFilters();
    applyFilters();
    built = true;
    document.body.dataset.ready = "1";
  }
  function paintLines(list) {
    for (const l of list) {
      const line = lines.get(l.name);
      if (!line) continue;
      line.data = l;
      const u = l.utilisation;
      const pct = u == null ? "–" : (100 * u).toFixed(1) + " %";
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
    const visible = new Map();
    for (const r of rows.values()) {
      const d = r.data;
      const show = (!st || d.state === st) && (!ln || d.line === ln) && (!text || d.name.toLowerCase().includes(text));
      r.tr.hidden = !show;
      if (show) { shown++; visible.set(d.line, true); }
      if (d.online) online++;
      if (d.state === "fault") faults++;
    }
    for (const [name, line] of lines) line.section.hidden = !visible.get(name);
    document.getElementById("summary").textContent =
      SB.t("devices_shown", { shown, total: rows.size, online, faults });
  }

  function update(msg) {
    offset = msg.now - Date.now() / 1000;
    if (!built) return;
    const announce = [];
    for (const d of msg.devices) {
      const r = rows.get(d.name);
      if (!r) continue;
      if (r.data.state !== d.state) announce.push(d.name + ": " + SB.stateText(d.state) + (d.fault ? " " + faultText(d) : ""));
      r.data = d;
      paint(r);
    }
    paintLines(msg.lines);
    if (msg.devices.length) applyFilters();
    if (announce.length) document.getElementById("announce").textContent = announce.slice(0, 5).join("; ");
  }

  document.addEventListener("DOMContentLoaded", () => {
    for (const id of ["filter-state", "filter-line", "filter-name"]) {
      document.getElementById(id).addEventListener("input", applyFilters);
    }
    document.getElementById("filters").addEventListener("submit", (e) => e.preventDefault());
    SB.stream((snap) => { offset = snap.now - Date.now() / 1000; build(snap); }, update);
    setInterval(() => { for (const r of rows.values()) if (!r.tr.hidden) r.cells.age.textContent = ageText(r.data); }, 1000);
    SB.langListeners.push(() => {
      for (const r of rows.values()) paint(r);
      for (const th of document.querySelectorAll("#lines th[data-i18n]")) th.textContent = SB.t(th.dataset.i18n);
      paintLines([...lines.values()].map((l) => l.data));
      fillFilters(); applyFilters();
    });
  });
})();
