/* The device page: status, actions (operators only, confirmed), parameters, events, starts, history, backup. */
"use strict";
(() => {
  const name = decodeURIComponent(location.pathname.split("/").pop());
  const base = "/api/devices/" + encodeURIComponent(name);
  let detail = null;
  let startPlot = null, historyPlot = null;
  let refreshing = false;

  function fmt(v) { return v == null ? "–" : typeof v === "number" ? String(v) : v; }

  function renderStatus() {
    const dl = document.getElementById("status");
    const row = detail.row, s = detail.status;
    SB.stateBadge(document.getElementById("device-state"), row.state);
    const items = [[SB.t("model"), detail.display_name + " (" + detail.model + ")"], [SB.t("filter_line"), detail.line],
      [SB.t("state"), SB.stateText(row.state)]];
    if (row.fault) items.push([SB.t("fault"), row.fault.code + ": " + SB.label(row.fault)]);
    const cur = Object.entries(row.currents || {}).map(([k, v]) => k.toUpperCase() + " " + v + " A").join(", ");
    items.push([SB.t("currents"), cur || "–"]);
    if (s) {
      for (const k of ["ready", "bus_control", "warning", "at_reference", "mains_voltage"]) {
        if (s[k] != null) items.push([k.replace("_", " "), s[k] ? "yes / 是" : "no / 否"]);
      }
      items.push(["raw", Object.entries(s.raw).map(([k, v]) => k + " " + v).join(", ")]);
    }
    if (row.error) items.push(["error", row.error]);
    dl.replaceChildren(...items.flatMap(([k, v]) => [SB.el("dt", { text: k }), SB.el("dd", { text: v })]));
  }

  function renderActions() {
    const hint = SB.actionHint();
    const h = document.getElementById("action-hint");
    h.hidden = !hint; h.textContent = hint;
    for (const b of document.querySelectorAll("[data-command]")) {
      const allowed = detail.remote.commands.includes(b.dataset.command);
      b.disabled = !SB.canAct() || !allowed;
      b.title = allowed ? "" : SB.t("not_allowed");
    }
    document.getElementById("restore-file").disabled = !SB.canAct();
  }

  function rangeText(p) {
    if (p.choices) return Object.entries(p.choices).map(([k, v]) => k + " = " + SB.label(v)).join(", ");
    return p.min + " … " + p.max + (p.step !== 1 ? " (× " + p.step + ")" : "");
  }
  function renderPoints() {
    const tbody = document.querySelector("#points tbody");
    const canAct = SB.canAct();
    const rows = detail.points.filter((p) => p.kind === "parameter" || p.now).map((p) => {
      const value = p.now ? (p.now.zh && SB.lang === "zh" ? p.now.zh + " (" + p.now.raw + ")" : p.now.text) : SB.t("not_polled");
      const cert = p.certainty.certainty;
      const certCell = SB.el("td", { class: "certainty-" + cert, text: cert + (p.certainty.why ? ": " + p.certainty.why : "") });
      const writeCell = SB.el("td", {});
      if (p.writable && detail.remote.write.includes(p.key)) {
        const input = SB.el("input", { "aria-label": SB.t("write") + " " + p.key, "data-key": p.key });
        const button = SB.el("button", { type: "button", text: SB.t("write"), "data-write": p.key });
        input.disabled = button.disabled = !canAct;
        button.addEventListener("click", () => write(p, input.value));
        writeCell.append(input, " ", button);
      } else if (p.writable) {
        writeCell.textContent = SB.t("not_allowed");
        writeCell.className = "muted";
      }
      return SB.el("tr", { "data-key": p.key }, SB.el("td", { text: p.address }),
        SB.el("th", { scope: "row", text: SB.label({ en: p.en, zh: p.zh }) + " · " + p.key }),
        SB.el("td", { class: "num", text: value }), SB.el("td", { text: p.unit }), SB.el("td", { text: rangeText(p) }),
        certCell, writeCell);
    });
    tbody.replaceChildren(...rows);
  }

  function showResult(text, ok) {
    const r = document.getElementById("action-result");
    r.className = ok ? "result-ok" : "result-bad";
    r.textContent = text;
  }
  function outcomeText(o) {
    if (o.key) return o.key + ": " + o.old + " → " + o.new + ", read back " + o.read_back + ": " + o.result;
    return o.action + ": " + o.before + " → " + o.reached + ": " + o.result + (o.error ? " (" + o.error + ")" : "");
  }
  async function act(path, body, question) {
    if (!(await SB.confirmDialog(question))) return;
    showResult(SB.t("sent"), true);
    try {
      const r = await SB.postJSON(base + path, body);
      showResult(r.outcomes.map(outcomeText).join("; "), r.ok);
    } catch (e) {
      const outs = e.body && e.body.outcomes ? " " + e.body.outcomes.map(outcomeText).join("; ") : "";
      showResult(e.message + outs, false);
    }
    refresh();
  }
  function command(cmd) {
    const label = SB.t(cmd);
    act("/command", { command: cmd }, SB.t("confirm_command", { what: label, device: name }));
  }
  function write(p, text) {
    const value = text.trim() === "" ? null : isNaN(Number(text)) ? text.trim() : Number(text);
    if (value == null) return;
    act("/write", { values: { [p.key]: value } }, SB.t("confirm_write", { key: p.key, value: text + " " + p.unit, device: name }));
  }

  async function refresh() {
    if (refreshing) return;
    refreshing = true;
    try {
      detail = await SB.getJSON(base);
      document.getElementById("device-name").textContent = name;
      document.title = name + " – starterbus";
      renderStatus(); renderActions();
      if (!document.querySelector("#points input:focus")) renderPoints();
      document.body.dataset.ready = "1";
    } finally { refreshing = false; }
  }

  async function loadEvents() {
    const ul = document.getElementById("events");
    try {
      const list = await SB.getJSON(base + "/events");
      ul.replaceChildren(...list.reverse().map((e) => SB.el("li", { "data-kind": e.kind },
        new Date(e.time * 1000).toLocaleString() + " · " + e.kind + " · " + e.text + (e.actor ? " · " + e.actor : "") +
        (e.currents_before && e.currents_before.length ? " · " + SB.t("currents") + ": " +
          e.currents_before.slice(-3).map((c) => ["a", "b", "c"].filter((k) => c[k] != null).map((k) => c[k]).join("/")).join(", ") : ""))));
    } catch (e) { ul.replaceChildren(SB.el("li", { class: "muted", text: e.status === 404 ? SB.t("no_history") : e.message })); }
  }

  function chartSize(el) { return { width: Math.max(300, el.clientWidth - 4), height: 300 }; }

  async function loadStarts() {
    const select = document.getElementById("start-select");
    let list = [];
    try { list = await SB.getJSON(base + "/starts"); } catch (e) {
      document.getElementById("start-note").textContent = e.status === 404 ? SB.t("no_history") : e.message; return;
    }
    const keep = select.value;
    select.replaceChildren(...list.slice().reverse().map((e) =>
      SB.el("option", { value: e.id, text: new Date(e.time * 1000).toLocaleString() + " · " + e.text })));
    if (keep && list.some((e) => String(e.id) === keep)) select.value = keep;
    if (list.length && (!startPlot || select.value !== keep)) plotStart(select.value);
  }
  async function plotStart(id) {
    const holder = document.getElementById("start-chart");
    const d = await SB.getJSON(base + "/starts/" + id);
    const series = [{ label: "t (s)" }];
    const data = [d.t];
    const colours = { a: "#b3261e", b: "#146c2e", c: "#0b5394" };
    for (const k of ["a", "b", "c"]) {
      if (d[k].some((v) => v != null)) { series.push({ label: SB.t("phase") + " " + k.toUpperCase() + " (A)", stroke: colours[k], width: 2 }); data.push(d[k]); }
    }
    if (d.limit_a != null) { series.push({ label: SB.t("limit") + " (A)", stroke: "#8a5a00", dash: [6, 4] }); data.push(d.t.map(() => d.limit_a)); }
    const peak = d.peak;
    const opts = {
      ...chartSize(holder), series, scales: { x: { time: false } }, cursor: { drag: { x: true, y: true } },
      axes: [{ label: "s" }, { label: "A" }],
      hooks: peak ? { draw: [(u) => {
        const x = u.valToPos(peak.t, "x", true), y = u.valToPos(peak.amps, "y", true);
        const c = u.ctx; c.save(); c.fillStyle = "#000"; c.beginPath(); c.arc(x, y, 5, 0, 2 * Math.PI); c.fill();
        c.font = "12px sans-serif"; c.fillText(SB.t("peak") + " " + peak.amps + " A", x + 8, y - 6); c.restore();
      }] } : {},
    };
    if (startPlot) startPlot.destroy();
    holder.replaceChildren();
    startPlot = new uPlot(opts, data, holder);
    holder.dataset.points = String(d.t.length);
    holder.setAttribute("aria-label", d.event.text + (peak ? "; " + SB.t("peak") + " " + peak.amps + " A" : ""));
    document.getElementById("start-note").textContent = d.event.text + (peak ? " · " + SB.t("peak") + " " + peak.amps + " A (" + peak.phase.toUpperCase() + ", t = " + peak.t + " s)" : "") +
      (d.limit_a != null ? " · " + SB.t("limit") + " " + d.limit_a + " A" : "");
  }

  async function loadHistoryKeys() {
    const select = document.getElementById("history-key");
    try {
      const r = await SB.getJSON(base + "/history");
      select.replaceChildren(...r.keys.map((k) => SB.el("option", { value: k, text: k })));
      plotHistory();
    } catch (e) { document.getElementById("history-note").textContent = e.status === 404 ? SB.t("no_history") : e.message; }
  }
  let historyAsked = 0;
  async function plotHistory() {
    const key = document.getElementById("history-key").value;
    if (!key) return;
    const span = Number(document.getElementById("history-range").value);
    const since = Date.now() / 1000 - span;
    const asked = ++historyAsked;  // a slower answer to an earlier choice must not replace this one
    const d = await SB.getJSON(base + "/history?key=" + encodeURIComponent(key) + "&since=" + since);
    if (asked !== historyAsked) return;
    const holder = document.getElementById("history-chart");
    if (historyPlot) historyPlot.destroy();
    holder.replaceChildren();
    historyPlot = new uPlot({ ...chartSize(holder), series: [{}, { label: key, stroke: "#0b5394", width: 2, spanGaps: false }],
      cursor: { drag: { x: true, y: false } } }, [d.t, d.v], holder);
    holder.dataset.key = key;
    holder.dataset.since = String(Math.floor(since));
    holder.dataset.points = String(d.v.filter((v) => v != null).length);
    document.getElementById("history-note").textContent = d.t.length + " samples" + (d.thinned > 1 ? " (every " + d.thinned + "th)" : "");
  }

  function renderDiff(rows, left, note) {
    const out = document.getElementById("diff");
    out.dataset.rows = String(rows.length);
    if (!rows.length) { out.replaceChildren(SB.el("p", { text: note + " " + SB.t("no_diff_any") })); return; }
    const table = SB.el("table", {}, SB.el("caption", { text: note }), SB.el("thead", {}, SB.el("tr", {},
      SB.el("th", { scope: "col", text: SB.t("key") }), SB.el("th", { scope: "col", text: left }),
      SB.el("th", { scope: "col", text: SB.t("device") }))));
    const tb = SB.el("tbody", {});
    for (const row of rows) {
      tb.append(SB.el("tr", { "data-key": row.key }, SB.el("th", { scope: "row", text: row.address + " " + row.key }),
        SB.el("td", { text: row.a }), SB.el("td", { text: row.b })));
    }
    table.append(tb);
    out.replaceChildren(table);
  }
  async function diffDefaults() {
    const out = document.getElementById("diff");
    out.textContent = SB.t("reading");
    try {
      const r = await SB.getJSON(base + "/backup?format=json");
      renderDiff(r.diff_defaults, "default", SB.t("diff_defaults") + ":");
    } catch (e) { out.textContent = e.message; }
  }
  async function diffFile(file) {
    const out = document.getElementById("diff");
    out.textContent = SB.t("reading");
    try {
      const r = await fetch(base + "/diff?file=" + encodeURIComponent(file.name), {
        method: "POST", credentials: "same-origin", headers: { "Content-Type": "application/octet-stream" }, body: file,
      });
      const body = await r.json().catch(() => ({ error: r.statusText }));
      if (!r.ok) { out.replaceChildren(SB.el("p", { class: "result-bad", role: "alert", text: body.error })); return; }
      renderDiff(body.diff, file.name, SB.t("diff_file") + ": " + file.name + (body.file.taken ? " (" + body.file.taken + ")" : ""));
    } catch (e) { out.textContent = e.message; }
    document.getElementById("diff-file").value = "";
  }

  async function restoreFile(file) {
    const text = await file.text();
    await act("/restore", { backup: text }, SB.t("confirm_restore", { device: name }));
    document.getElementById("restore-file").value = "";
  }

  document.addEventListener("DOMContentLoaded", () => {
    document.getElementById("backup-link").href = base + "/backup";
    for (const b of document.querySelectorAll("[data-command]")) b.addEventListener("click", () => command(b.dataset.command));
    document.getElementById("diff-button").addEventListener("click", diffDefaults);
    document.getElementById("diff-file").addEventListener("change", (e) => { if (e.target.files[0]) diffFile(e.target.files[0]); });
    document.getElementById("restore-file").addEventListener("change", (e) => { if (e.target.files[0]) restoreFile(e.target.files[0]); });
    document.getElementById("start-select").addEventListener("change", (e) => plotStart(e.target.value));
    document.getElementById("history-key").addEventListener("change", plotHistory);
    document.getElementById("history-range").addEventListener("change", plotHistory);
    SB.sessionListeners.push(() => { if (detail) { renderActions(); renderPoints(); } });
    SB.langListeners.push(() => { if (detail) { renderStatus(); renderActions(); renderPoints(); } });
    refresh().then(() => { loadEvents(); loadStarts(); loadHistoryKeys(); });
    let last = 0;
    SB.stream(() => null, (msg) => {
      const mine = msg.devices.find((d) => d.name === name);
      if (!mine || !detail) return;
      const changed = mine.state !== detail.row.state;
      detail.row = mine; renderStatus();
      if (changed) { renderActions(); loadEvents(); loadStarts(); }
      if (Date.now() - last > 5000) { last = Date.now(); refresh(); }
    });
  });
})();
