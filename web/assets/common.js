/* starterbus web: what every page shares (texts in two languages, the session, the API, dialogs). */
"use strict";
const SB = (() => {
  const TEXT = {
    en: {
      fleet_title: "Soft starters", device_title: "Device", login: "Log in", logout: "Log out", user: "User",
      password: "Password", cancel: "Cancel", confirm: "Confirm", all: "all", filter_state: "State",
      filter_line: "Line", filter_name: "Name", device: "Device", model: "Model", state: "State", fault: "Fault",
      currents: "Currents", last_poll: "Last poll", offline_for: "offline for", utilisation: "line use",
      devices_shown: "{shown} of {total} devices shown; {online} online, {faults} in fault",
      live: "live", reconnecting: "reconnecting…", read_only: "read-only", ago: "{t} ago",
      "role_read-only": "read-only", role_operator: "operator",
      login_failed: "Login refused: wrong user name or password, or too many attempts.",
      parameters: "Parameters", measurements: "Measurements", status: "Status", events: "Events",
      starts: "Recorded starts", history: "History", backup: "Backup", actions: "Actions",
      start: "Start", stop: "Stop", reset: "Fault reset", write: "Write", key: "Key", label: "Name",
      value: "Value", unit: "Unit", range: "Range", certainty: "Certainty", address: "Address",
      confirm_command: "Send “{what}” to {device}?", confirm_write: "Write {key} = {value} to {device}?",
      confirm_restore: "Restore the backup into {device}? Only differing, allowed parameters are written.",
      no_history: "No history: start serve with --record DB.", not_polled: "not polled",
      download_backup: "Download a backup (reads every parameter)", diff_defaults: "Compare with the defaults", diff_file: "Compare with a backup file", no_diff_any: "No difference.",
      restore: "Restore a backup file", actions_login: "Log in as an operator to act.",
      actions_tls: "Actions need TLS (https).", actions_readonly: "Your role is read-only.",
      not_allowed: "not allowed by the fleet file", result: "Result", show: "Show", range_last: "Last",
      peak: "peak", limit: "current limit", phase: "phase", back: "← all devices",
      sent: "sending…", offline: "offline", online: "online", since: "since", time: "Time", kind: "What",
      who: "Who", devices: "devices", polled_every: "polled every {p} s", reading: "reading…",
    },
    zh: {
      fleet_title: "软起动器", device_title: "设备", login: "登录", logout: "退出", user: "用户", password: "密码",
      cancel: "取消", confirm: "确认", all: "全部", filter_state: "状态", filter_line: "线路", filter_name: "名称",
      device: "设备", model: "型号", state: "状态", fault: "故障", currents: "电流", last_poll: "上次轮询",
      offline_for: "离线", utilisation: "线路占用", devices_shown: "显示 {shown}/{total} 台；{online} 台在线，{faults} 台故障",
      live: "实时", reconnecting: "重新连接…", read_only: "只读", ago: "{t} 前",
      "role_read-only": "只读", role_operator: "操作员",
      login_failed: "登录被拒绝：用户名或密码错误，或尝试次数过多。",
      parameters: "参数", measurements: "测量值", status: "状态", events: "事件", starts: "记录的起动",
      history: "历史", backup: "备份", actions: "操作", start: "起动", stop: "停车", reset: "故障复位", write: "写入",
      key: "键", label: "名称", value: "值", unit: "单位", range: "范围", certainty: "可信度", address: "地址",
      confirm_command: "向 {device} 发送“{what}”？", confirm_write: "向 {device} 写入 {key} = {value}？",
      confirm_restore: "将备份恢复到 {device}？只写入不同且允许的参数。",
      no_history: "无历史：用 serve --record DB 启动。", not_polled: "未轮询",
      download_backup: "下载备份（读取全部参数）", diff_defaults: "与默认值比较", diff_file: "与备份文件比较", no_diff_any: "没有差异。", restore: "恢复备份文件",
      actions_login: "以操作员身份登录后才能操作。", actions_tls: "操作需要 TLS (https)。", actions_readonly: "您的角色为只读。",
      not_allowed: "设备清单未允许", result: "结果", show: "显示", range_last: "最近", peak: "峰值", limit: "限流值",
      phase: "相", back: "← 全部设备", sent: "发送中…", offline: "离线", online: "在线",
      since: "自", time: "时间", kind: "类型", who: "操作者", devices: "台设备", polled_every: "每 {p} 秒轮询", reading: "读取中…",
    },
  };
  const STATES = {
    ready: ["ready", "就绪", "○"], stopped: ["stopped", "停止", "■"], starting: ["starting", "起动中", "▲"],
    running: ["running", "运行", "●"], stopping: ["stopping", "停车中", "▼"], fault: ["fault", "故障", "✖"],
    offline: ["offline", "离线", "?"], unknown: ["unknown", "未知", "…"],
  };
  let lang = localStorage.getItem("starterbus-lang") === "zh" ? "zh" : "en";
  const langListeners = [];

  function t(key, vars) {
    let s = (TEXT[lang] && TEXT[lang][key]) || TEXT.en[key] || key;
    for (const [k, v] of Object.entries(vars || {})) s = s.replace("{" + k + "}", v);
    return s;
  }
  function applyTexts(root) {
    document.documentElement.lang = lang === "zh" ? "zh-CN" : "en";
    for (const el of (root || document).querySelectorAll("[data-i18n]")) el.textContent = t(el.dataset.i18n);
    const button = document.getElementById("lang");
    if (button) button.textContent = lang === "zh" ? "English" : "中文";
  }
  function setLang(next) {
    lang = next;
    localStorage.setItem("starterbus-lang", lang);
    applyTexts();
    for (const fn of langListeners) fn(lang);
  }
  function stateText(state) { const s = STATES[state] || STATES.unknown; return lang === "zh" ? s[1] : s[0]; }
  function stateBadge(el, state) {
    const s = STATES[state] ? state : "unknown";
    el.className = "state s-" + s;
    el.dataset.mark = STATES[s][2];
    el.dataset.state = s;
    el.textContent = stateText(s);
  }
  function label(obj) { return lang === "zh" && obj && obj.zh ? obj.zh : obj ? obj.en : ""; }
  function age(seconds) {
    if (seconds == null || !isFinite(seconds)) return "–";
    seconds = Math.max(0, seconds);
    if (seconds < 60) return seconds.toFixed(seconds < 10 ? 1 : 0) + " s";
    if (seconds < 3600) return Math.floor(seconds / 60) + " min " + Math.floor(seconds % 60) + " s";
    if (seconds < 86400) return Math.floor(seconds / 3600) + " h " + Math.floor((seconds % 3600) / 60) + " min";
    return Math.floor(seconds / 86400) + " d";
  }
  function el(tag, attrs, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === "class") e.className = v; else if (k === "text") e.textContent = v; else e.setAttribute(k, v);
    }
    for (const c of children) if (c != null) e.append(c);
    return e;
  }

  // -- the API ------------------------------------------------------------------------------------------
  const session = { user: null, role: null, csrf: null, logins: false, actions_allowed: false, history: false };
  const sessionListeners = [];
  async function getJSON(path) {
    const r = await fetch(path, { credentials: "same-origin" });
    const body = await r.json().catch(() => ({ error: r.statusText }));
    if (!r.ok) throw Object.assign(new Error(body.error || r.statusText), { status: r.status, body });
    return body;
  }
  async function postJSON(path, data) {
    const r = await fetch(path, {
      method: "POST", credentials: "same-origin",
      headers: { "Content-Type": "application/json", "X-CSRF-Token": session.csrf || "" },
      body: JSON.stringify(data || {}),
    });
    const body = await r.json().catch(() => ({ error: r.statusText }));
    if (!r.ok) throw Object.assign(new Error(body.error || r.statusText), { status: r.status, body });
    return body;
  }
  async function refreshSession() {
    Object.assign(session, await getJSON("/api/session"));
    renderSession();
  }
  function renderSession() {
    const who = document.getElementById("who");
    if (who) who.textContent = session.user ? session.user + " (" + t("role_" + session.role) + ")" : t("read_only");
    const inB = document.getElementById("login-button"), outB = document.getElementById("logout-button");
    if (inB) inB.hidden = !!session.user || !session.logins;
    if (outB) outB.hidden = !session.user;
    for (const fn of sessionListeners) fn(session);
  }
  function canAct() { return session.role === "operator" && session.actions_allowed; }
  function actionHint() {
    if (!session.actions_allowed) return t("actions_tls");
    if (!session.user) return t("actions_login");
    if (session.role !== "operator") return t("actions_readonly");
    return "";
  }

  function setupLogin() {
    const dialog = document.getElementById("login-dialog");
    const form = document.getElementById("login-form");
    document.getElementById("login-button").addEventListener("click", () => {
      document.getElementById("login-error").textContent = "";
      dialog.showModal();
      document.getElementById("login-user").focus();
    });
    document.getElementById("login-cancel").addEventListener("click", () => dialog.close());
    form.addEventListener("submit", async (ev) => {
      ev.preventDefault();
      const user = document.getElementById("login-user").value;
      const password = document.getElementById("login-password").value;
      try {
        const r = await postJSON("/api/login", { user, password });
        Object.assign(session, r);
        document.getElementById("login-password").value = "";
        dialog.close();
        renderSession();
      } catch (e) {
        document.getElementById("login-error").textContent = e.status === 401 ? t("login_failed") : e.message;
      }
    });
    document.getElementById("logout-button").addEventListener("click", async () => {
      await postJSON("/api/logout", {}).catch(() => null);
      Object.assign(session, { user: null, role: null, csrf: null });
      renderSession();
    });
  }

  // -- a confirmation dialog (a promise of true / false) ---------------------------------------------------
  function confirmDialog(question) {
    return new Promise((resolve) => {
      const d = el("dialog", { id: "confirm-dialog", "aria-labelledby": "confirm-text", role: "alertdialog" });
      const ok = el("button", { type: "button", class: "primary", id: "confirm-ok", text: t("confirm") });
      const no = el("button", { type: "button", id: "confirm-cancel", text: t("cancel") });
      d.append(el("p", { id: "confirm-text", text: question }), el("menu", {}, no, ok));
      document.body.append(d);
      const done = (v) => { d.close(); d.remove(); resolve(v); };
      ok.addEventListener("click", () => done(true));
      no.addEventListener("click", () => done(false));
      d.addEventListener("cancel", () => done(false));
      d.showModal();
      no.focus();
    });
  }

  // -- server-sent events ---------------------------------------------------------------------------------
  // url: "/api/stream?after=ID" continues from the rows of a snapshot with that id (only what changed since)
  function stream(onSnapshot, onUpdate, url) {
    const conn = document.getElementById("conn");
    const source = new EventSource(url || "/api/stream");
    source.addEventListener("open", () => { if (conn) conn.textContent = t("live"); });
    source.addEventListener("snapshot", (e) => onSnapshot(JSON.parse(e.data)));
    source.addEventListener("update", (e) => onUpdate(JSON.parse(e.data)));
    source.addEventListener("error", () => { if (conn) conn.textContent = t("reconnecting"); });
    return source;
  }

  document.addEventListener("DOMContentLoaded", () => {
    applyTexts();
    const button = document.getElementById("lang");
    if (button) button.addEventListener("click", () => setLang(lang === "zh" ? "en" : "zh"));
    if (document.getElementById("login-dialog")) setupLogin();
    refreshSession().catch(() => null);
  });

  return {
    t, applyTexts, stateText, stateBadge, label, age, el, getJSON, postJSON, session, sessionListeners,
    langListeners, canAct, actionHint, confirmDialog, stream, STATES, get lang() { return lang; },
  };
})();
