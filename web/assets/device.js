/* The device page: status, actions (operators only, confirmed), parameters, events, starts, history, backup. */
"use strict";
(() => {
  const name = decodeURIComponent(location.pathname.split("/").pop());
  const base = "/api/devices/" + encodeURIComponent(name);
  let detail = null;
  let startPlot = null, historyPlot = null;
  let refreshing = false;
  const MAX_UPLOAD = 256 * 1024;  // as the API's (a backup file is a few kB)
  // this page's own texts (the shared ones are SB.t's)
  const TEXT = {
    en: {
      event: "Event", account: "system account", before_trip: "before the trip", no_events: "No event recorded yet.", no_starts: "No start recorded yet.",
      too_large: "{file}: larger than 256 kB, not a backup file; nothing sent",
      nothing_differs: "restore: the device already has every value of the backup; nothing written",
      kinds: { fault: "fault", state: "state", offline: "offline", online: "online", write: "write", command: "command",
        start: "recorded start", gap: "recording gap", dcmd: "MQTT command refused" },
    },
    zh: {
      event: "事件", account: "系统账户", before_trip: "跳闸前", no_events: "尚无事件记录。", no_starts: "尚无起动记录。",
      too_large: "{file}：大于 256 kB，不是备份文件；未发送",
      nothing_differs: "恢复：设备已具有备份中的全部值；未写入",
      kinds: { fault: "故障", state: "状态变化", offline: "离线", online: "恢复在线", write: "写入", command: "命令",
        start: "记录的起动", gap: "记录中断", dcmd: "MQTT 命令被拒绝" },
    },
  };
  function tt(key, vars) {
    let s = (TEXT[SB.lang] || TEXT.en)[key] || TEXT.en[key] || key;
    for (const [k, v] of Object.entries(vars || {})) s = s.replace("{" + k + "}", v);
    return s;
  }
  function kindText(kind) { return (TEXT[SB.lang] || TEXT.en).kinds[kind] || kind; }
  function applyLocalTexts() { for (const e of document.querySelectorAll("[data-dt]")) e.textContent = tt(e.dataset.dt); }

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
        input.addEventListener("keydown", (e) => {  // Enter writes; its default would press the dialog's Cancel
          if (e.key === "Enter") { e.preventDefault(); write(p, input.value); }
        });
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
    const focused = document.activeElement;  // a keyboard user's place survives the re-render
    const again = focused && tbody.contains(focused) && focused.dataset.write
      ? "[data-write='" + CSS.escape(focused.dataset.write) + "']" : null;
    tbody.replaceChildren(...rows);
    if (again) { const b = tbody.querySelector(again); if (b && !b.disabled) b.focus(); }
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
    const from = document.activeElement;
    const confirmed = await SB.confirmDialog(question);
    if (from && from.isConnected && typeof from.focus === "function") from.focus();  // back where the user was
    if (!confirmed) return;
    showResult(SB.t("sent"), true);
    try {
      const r = await SB.postJSON(base + path, body);
      showResult(r.outcomes.length ? r.outcomes.map(outcomeText).join("; ") : tt("nothing_differs"), r.ok);
    } catch (e) {
      const outs = e.body && e.body.outcomes ? " " + e.body.outcomes.map(outcomeText).join("; ") : "";
      showResult(e.message + outs, false);
    }
    refresh();
    loadEvents();
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

  // -- the event log: the last 500, then what the history has written since (GET .../events?after=ID) ----------
  let events = [], lastEventId = null, eventsBusy = false, eventsAgain = false, eventsAt = 0, eventsFullAt = 0;
  async function loadEvents() {
    if (eventsBusy) { eventsAgain = true; return; }
    eventsBusy = true;
    try {
      do {
        eventsAgain = false;
        eventsAt = Date.now();
        // now and then the whole list again: a history file replaced (its ids start over) is seen too
        const full = lastEventId == null || eventsAt - eventsFullAt > 60000;
        const fresh = await SB.getJSON(base + "/events" + (full ? "" : "?after=" + lastEventId));
        if (full) { eventsFullAt = eventsAt; events = []; }
        const seen = new Set(events.map((e) => e.id));
        const added = fresh.filter((e) => !seen.has(e.id));
        if (full || added.length) {
          events = events.concat(added).sort((a, b) => a.time - b.time || a.id - b.id).slice(-500);
          lastEventId = events.reduce((m, e) => Math.max(m, e.id), 0);
          renderEvents(full ? new Set() : new Set(added.map((e) => e.id)));
        }
      } while (eventsAgain);
    } catch (e) {
      document.getElementById("events-note").textContent = e.status === 404 ? SB.t("no_history") : e.message;
    } finally { eventsBusy = false; }
  }
  function beforeTrip(e) {
    const list = (e.currents_before || []).slice(-3);
    if (!list.length) return null;
    return tt("before_trip") + ": " + list.map((c) => (c.time != null ? "t" + (c.time - e.time).toFixed(1) + " s " : "") +
      ["a", "b", "c"].filter((k) => c[k] != null).map((k) => c[k]).join("/") + " A").join(", ");
  }
  function renderEvents(fresh) {
    const rows = events.slice().reverse().map((e) => {
      const before = beforeTrip(e);
      return SB.el("tr", { "data-kind": e.kind, "data-id": String(e.id), "data-actor": e.actor || "", class: fresh.has(e.id) ? "fresh" : "" },
        SB.el("td", { class: "when", text: new Date(e.time * 1000).toLocaleString() }),
        SB.el("td", { class: "what", text: kindText(e.kind) }),
        SB.el("td", { class: "text" }, SB.lang === "zh" && e.zh ? e.zh : e.text, before ? SB.el("span", { class: "before", text: before }) : null),
        SB.el("td", { class: "who", text: e.actor || (e.user ? e.user + " (" + tt("account") + ")" : "–") }));
    });
    document.querySelector("#events tbody").replaceChildren(...rows);
    document.getElementById("events-note").textContent = events.length ? "" : tt("no_events");
    document.getElementById("events").dataset.loaded = "1";
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
    document.getElementById("start-pick").hidden = document.getElementById("start-chart").hidden = !list.length;
    if (!list.length) document.getElementById("start-note").textContent = tt("no_starts");
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
  function tooLarge(file) { return file.size > MAX_UPLOAD ? tt("too_large", { file: file.name }) : null; }
  async function diffFile(file) {
    const out = document.getElementById("diff");
    const big = tooLarge(file);
    if (big) {
      out.replaceChildren(SB.el("p", { class: "result-bad", role: "alert", text: big }));
      document.getElementById("diff-file").value = "";
      return;
    }
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
    const big = tooLarge(file);
    if (big) showResult(big, false);
    else await act("/restore", { backup: await file.text() }, SB.t("confirm_restore", { device: name }) + " (" + file.name + ")");
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
    SB.langListeners.push(() => {
      applyLocalTexts();
      if (detail) { renderStatus(); renderActions(); renderPoints(); renderEvents(new Set()); }
    });
    applyLocalTexts();
    refresh().then(() => { loadEvents(); loadStarts(); loadHistoryKeys(); });
    let last = 0;
    SB.stream(() => null, (msg) => {  // this device's row only (not the fleet's: a tablet on a 1,000-device plant)
      const mine = msg.devices.find((d) => d.name === name);
      if (!mine || !detail) return;
      const changed = mine.state !== detail.row.state;
      detail.row = mine; renderStatus();
      loadEvents();  // a new poll of this device: the history has recorded what happened before it
      if (changed) { renderActions(); loadStarts(); }
      if (Date.now() - last > 5000) { last = Date.now(); refresh(); }
    }, "/api/stream?device=" + encodeURIComponent(name));
    let resizing = null;  // a tablet turned, a window resized: the charts take the new width
    window.addEventListener("resize", () => {
      clearTimeout(resizing);
      resizing = setTimeout(() => {
        for (const [plot, id] of [[startPlot, "start-chart"], [historyPlot, "history-chart"]]) {
          if (plot) plot.setSize(chartSize(document.getElementById(id)));
        }
      }, 200);
    });
    // without updates of this device (offline, or the stream reconnecting), the events are asked for anyway
    setInterval(() => {
      const every = Math.max(2, detail ? detail.period : 2) * 1000;
      if (Date.now() - eventsAt > every) loadEvents();
    }, 1000);
  });
})();
