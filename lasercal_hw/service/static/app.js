// lasercal operator page: plain JavaScript against the daemon's /v1 API (docs/daemon.md).
// Live state comes from the /v1/events stream; drawing happens once per animation frame, and
// every event's arrival and paint time is kept in window.lasercalEvents (read by the browser tests).
"use strict";

const TOKEN_KEY = "lasercal.token";
const ACTIVE_STATES = new Set(["queued", "preflight", "running", "solving"]);
const STATUS_POLL_MS = 5000;
const EVENT_LOG_LINES = 200;
const INSET_PX = 150;

const $ = (id) => document.getElementById(id);

const state = {
  status: null,
  health: null,           // GET /v1/health: every scanner's calibration at a glance
  job: null,              // the job shown in the run panel
  calibrations: [],
  trajectories: [],       // GET /v1/trajectories: presets and designed waypoint files
  verifies: [],
  diffs: new Map(),       // "<id>:<active id>" -> diff document
  selected: null,         // the scanner chosen on a cell's page (null: every scanner)
  exports: null,          // GET /v1/calibration?scanner=<selected>: its active calibration's exports
  knownJobs: new Set(),   // jobs older than the latest one when the page opened
  live: freshLive(null),
};

/** What the run panel draws for one job: per scanner its scans and centres (a cell job's
 *  events name their scanner; a one-scanner job's are of "default"). */
function freshLive(jobId) {
  return { jobId, progress: null, scans: 0, current: null, scanners: new Map(), results: new Map(),
           skipped: [], log: [] };
}

function emptyScannerLive() { return { scan: null, scans: 0, centres: new Map(), predicted: new Map() }; }

/** The live picture of scanner ``name`` (made on its first event). */
function scannerLive(name) {
  const live = state.live;
  if (!live.scanners.has(name)) live.scanners.set(name, emptyScannerLive());
  return live.scanners.get(name);
}

/** The scanner the picture shows: the chosen one, else the one the run is at. */
function shownLive() {
  const name = state.selected || state.live.current;
  return { name, ...(state.live.scanners.get(name) || emptyScannerLive()) };
}

/** True when the daemon's cell names its scanners ([scanners.NAME]): the page shows them one by one. */
function isCell() {
  const scanners = (state.status && state.status.scanners) || [];
  return scanners.some((s) => s.name !== "default");
}

/** A scanner's active calibration in the history (each scanner has its own). */
function activeOf(scanner) {
  return state.calibrations.find((c) => c.active && (c.scanner || "default") === scanner) || null;
}

// ---- event-to-paint record --------------------------------------------------------------

/** One entry per received event: arrival, render and paint times in epoch milliseconds. */
window.lasercalEvents = [];
let unpainted = [];
const dirty = new Set();
let frameRequested = false;

function epochMs() { return performance.timeOrigin + performance.now(); }

function markDirty(...parts) {
  parts.forEach((p) => dirty.add(p));
  if (!frameRequested) {
    frameRequested = true;
    requestAnimationFrame(renderFrame);
  }
}

function renderFrame() {
  frameRequested = false;
  const parts = new Set(dirty);
  dirty.clear();
  if (parts.has("status")) renderStatus();
  if (parts.has("job")) renderJob();
  if (parts.has("scan")) renderScan();
  if (parts.has("log")) renderLog();
  if (parts.has("history")) renderHistory();
  const rendered = unpainted;
  unpainted = [];
  const renderedAt = epochMs();
  rendered.forEach((e) => { e.render_ms = renderedAt; });
  // The next frame's callback runs after this frame was painted.
  requestAnimationFrame(() => {
    const paintedAt = epochMs();
    rendered.forEach((e) => { e.paint_ms = paintedAt; });
  });
}

// ---- HTTP ---------------------------------------------------------------------------------

class ApiError extends Error {
  constructor(status, body) {
    super(body && body.message ? body.message : `HTTP ${status}`);
    this.status = status;
    this.code = body && body.code ? body.code : "http_" + status;
  }
}

async function api(method, path, body, token) {
  const headers = { Accept: "application/json" };
  if (body !== undefined) headers["Content-Type"] = "application/json";
  if (token) headers.Authorization = "Bearer " + token;
  const response = await fetch(path, { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
  const text = await response.text();
  let parsed = null;
  try { parsed = text ? JSON.parse(text) : null; } catch (_) { parsed = { message: text.slice(0, 200) }; }
  if (!response.ok) throw new ApiError(response.status, parsed);
  return parsed;
}

/** A call that needs the token: asks for it once, and again if the daemon refuses it. */
async function authorised(method, path, body) {
  for (let attempt = 0; attempt < 2; attempt++) {
    let token = sessionStorage.getItem(TOKEN_KEY);
    if (!token) {
      token = await askToken();
      if (!token) return null;
      sessionStorage.setItem(TOKEN_KEY, token);
    }
    try {
      const answer = await api(method, path, body, token);
      showError("");
      return answer;
    } catch (err) {
      if (err.status === 401 || err.status === 403) {
        sessionStorage.removeItem(TOKEN_KEY);
        showError(`${err.message} (${err.code}); enter the token again`);
        continue;
      }
      throw err;
    }
  }
  return null;
}

function showError(message) {
  const line = $("error-line");
  line.textContent = message;
  line.hidden = !message;
}

// ---- dialogs ------------------------------------------------------------------------------

function dialogResult(dialog) {
  return new Promise((resolve) => {
    dialog.addEventListener("close", () => resolve(dialog.returnValue), { once: true });
    dialog.returnValue = "";
    dialog.showModal();
  });
}

async function askToken() {
  const input = $("token-input");
  input.value = "";
  const answer = await dialogResult($("token-dialog"));
  return answer === "ok" && input.value.trim() ? input.value.trim() : null;
}

async function confirmAction(title, text, yesLabel) {
  $("confirm-title").textContent = title;
  $("confirm-text").textContent = text;
  $("confirm-yes").textContent = yesLabel;
  return (await dialogResult($("confirm-dialog"))) === "ok";
}

// ---- formatting ---------------------------------------------------------------------------

const fmt = (x, digits = 2) => (x === null || x === undefined || Number.isNaN(x) ? "–" : Number(x).toFixed(digits));
const norm = (v) => (v ? Math.hypot(...v) : null);
/** The largest component of a std vector: what the CLI calls the std. */
const largest = (v) => (v && v.length ? Math.max(...v.map(Math.abs)) : null);

/** "t = (x, y, z) mm, euler zyx (yaw, pitch, roll) deg" of a 4x4 T_base_laser. */
function poseText(T) {
  if (!T) return "";
  const deg = (r) => (r * 180) / Math.PI;
  const yaw = deg(Math.atan2(T[1][0], T[0][0]));
  const pitch = deg(Math.asin(Math.max(-1, Math.min(1, -T[2][0]))));
  const roll = deg(Math.atan2(T[2][1], T[2][2]));
  const t = [T[0][3], T[1][3], T[2][3]].map((v) => fmt(v * 1000, 1)).join(", ");
  return `T_base_laser: t = (${t}) mm, euler zyx (${[yaw, pitch, roll].map((v) => fmt(v, 3)).join(", ")}) deg`;
}

/** Standard deviation of |d| from the per-axis std (first order; RMS of the axes at d = 0). */
function normStd(d, std) {
  if (!d || !std) return null;
  const n = Math.hypot(...d);
  if (n < 1e-12) return Math.sqrt(std.reduce((s, x) => s + x * x, 0) / std.length);
  return Math.sqrt(d.reduce((s, x, i) => s + (x / n) ** 2 * std[i] ** 2, 0));
}

function age(isoTime) {
  const seconds = (Date.now() - Date.parse(isoTime)) / 1000;
  if (!Number.isFinite(seconds)) return "";
  if (seconds < 120) return `${Math.round(seconds)} s ago`;
  if (seconds < 7200) return `${Math.round(seconds / 60)} min ago`;
  if (seconds < 172800) return `${Math.round(seconds / 3600)} h ago`;
  return `${Math.round(seconds / 86400)} days ago`;
}

const utc = (iso) => (iso ? iso.replace("T", " ").replace(/\.\d+/, "").replace(/\+00:00|Z$/, "") : "–");

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  Object.entries(attrs).forEach(([k, v]) => {
    if (k === "class") node.className = v; else if (k === "text") node.textContent = v; else node.setAttribute(k, v);
  });
  children.forEach((c) => node.append(c));
  return node;
}

function badge(text, kind) { return el("span", { class: "badge " + kind, text }); }

function stateKind(jobState) {
  if (ACTIVE_STATES.has(jobState)) return "run";
  return { succeeded: "ok", failed: "bad", cancelled: "warn", interrupted: "warn" }[jobState] || "off";
}

// ---- status panel -------------------------------------------------------------------------

function renderStatus() {
  const s = state.status;
  if (!s) return;
  const cell = isCell();
  document.body.classList.toggle("cell", cell);
  if (cell) {
    renderScannerCards();
    renderScannerFilter();
  }
  renderHealth();
  $("daemon-version").textContent = `daemon ${s.daemon.version}`;
  $("dry-run-badge").hidden = !s.daemon.dry_run;
  const robot = s.robot || {};
  const robotNode = $("robot-status");
  robotNode.replaceChildren(
    badge(robot.connected ? "connected" : "not connected", robot.connected ? "ok" : "bad"), " ",
    el("span", { text: robot.host || "" }),
    el("div", { class: "small", text: `mode ${robot.mode || "–"} · safety ${robot.safety || "–"} · remote control ${
      robot.remote_control === true ? "on" : robot.remote_control === false ? "off" : "–"}` }));
  if (robot.error) robotNode.append(el("div", { class: "small bad-text", text: robot.error }));
  const scanner = s.scanner || {};
  const identity = scanner.identity ? Object.entries(scanner.identity).map(([k, v]) => `${k} ${v}`).join(" · ") : "";
  const scannerNode = $("scanner-status");
  scannerNode.replaceChildren(
    badge(scanner.connected ? "connected" : "not connected", scanner.connected ? "ok" : "bad"), " ",
    el("span", { class: "small", text: scanner.url || "" }),
    el("div", { class: "small", text: identity }));
  if (scanner.error) scannerNode.append(el("div", { class: "small", text: scanner.error }));
  const active = s.active_calibration;
  const activeNode = $("active-calibration");
  if (!active) {
    activeNode.replaceChildren(el("span", { class: "muted", text: "none" }));
  } else {
    const lastVerify = state.verifies.find((v) => v.calibration_id === active.id);
    activeNode.replaceChildren(
      el("span", { class: "mono", text: active.id }), " ",
      badge(active.passed ? "passed" : "failed", active.passed ? "ok" : "bad"),
      active.dry_run ? badge("dry run", "warn") : "",
      el("div", { class: "small", text: `${utc(active.created_utc)} (${age(active.created_utc)})` }),
      el("div", { class: "small", text: poseText(active.T_base_laser) }),
      el("div", { class: "small", text: `std (largest axis) ${fmt(largest(active.std_translation_mm))} mm, ${
        fmt(largest(active.std_rotation_deg), 3)} deg` }),
      el("div", { class: "small", text: lastVerify ? `last verify: ${lastVerify.verdict} (${age(lastVerify.created_utc)})`
        : "not verified since" }));
  }
}

const VERDICT_KIND = { ok: "ok", inconclusive: "warn", degraded: "warn", recalibrate: "bad" };

/** Seconds as "45 s", "12 min", "5 h", "3 days". */
function duration(seconds) {
  if (seconds < 120) return `${Math.round(seconds)} s`;
  if (seconds < 7200) return `${Math.round(seconds / 60)} min`;
  if (seconds < 172800) return `${Math.round(seconds / 3600)} h`;
  return `${Math.round(seconds / 86400)} days`;
}

/** One line per scanner: its calibration's age, the last verify's verdict, the robot's calibration. */
function renderHealth() {
  const node = $("health");
  if (!state.health) return;
  node.replaceChildren(...state.health.scanners.map((s) => {
    const row = el("div", { class: "health-row", "data-scanner": s.name }, el("span", { class: "mono", text: s.name }), " ");
    row.append(...healthBadges(s));
    return row;
  }));
}

/** A scanner's health at a glance: its calibration (passed, age), its last verify (verdict,
 *  when), whether the robot's kinematics calibration still matches and the scanner's range
 *  error against its data sheet (why, on hover). */
function healthBadges(s) {
  if (!s.active_calibration) return [badge("no active calibration", "off")];
  const verify = s.last_verify;
  const robot = s.robot_calibration_matches;
  const badges = [
    badge(`${s.passed ? "passed" : "failed"} · ${duration(s.age_s)} old`, s.passed ? "ok" : "bad"), " ",
    verify ? badge(`verify ${verify.verdict} · ${duration(verify.age_s)} ago`, VERDICT_KIND[verify.verdict] || "off")
      : badge("never verified", "warn"), " ",
    el("span", { title: s.robot_calibration_note }, badge(
      robot === true ? "robot calibration same" : robot === false ? "robot calibration changed" : "robot calibration unknown",
      robot === true ? "ok" : robot === false ? "bad" : "off")), " ",
    rangeErrorBadge(s.range_error)];
  if (robot === false) badges.push(el("div", { class: "small bad-text", text: s.robot_calibration_note }));
  return badges;
}

/** The active calibration's largest range error against the data sheet (the note on hover). */
function rangeErrorBadge(range) {
  const text = range.worst_mm === null ? "range error not estimated"
    : `range error ${range.worst_mm.toFixed(1)} mm`;
  const kind = { within_data_sheet: "ok", beyond_data_sheet: "bad" }[range.state] || "off";
  return el("span", { title: range.note, class: "range-error" }, badge(text, kind));
}

/** A cell's scanners, one card each: connection, health, active calibration; a click chooses
 *  the scanner the history, its exports and the scan picture show (again: every scanner). */
function renderScannerCards() {
  const health = new Map(((state.health && state.health.scanners) || []).map((h) => [h.name, h]));
  $("scanner-cards").replaceChildren(...state.status.scanners.map((s) => {
    const held = s.in_use_by_job;
    const connection = held ? badge(`in use by ${held}`, "run")
      : badge(s.connected ? "connected" : "not connected", s.connected ? "ok" : "bad");
    const card = el("div", { class: "scanner-card" + (state.selected === s.name ? " selected" : ""),
                             "data-scanner": s.name, role: "button", tabindex: "0",
                             title: `show ${s.name}'s history, exports and scans` },
      el("div", {}, el("span", { class: "mono name", text: s.name }), " ", connection, " ",
        el("span", { class: "small muted", text: s.url || "" })));
    if (s.error && !held) card.append(el("div", { class: "small", text: s.error }));
    const h = health.get(s.name);
    if (h) card.append(el("div", { class: "health-row" }, ...healthBadges(h)));
    const active = activeOf(s.name);
    if (active) {
      card.append(
        el("div", { class: "small" }, "active ", el("span", { class: "mono", text: active.id }),
          active.dry_run ? " (dry run)" : "", ` · ${utc(active.created_utc)}`),
        el("div", { class: "small pose", text: poseText(active.T_base_laser) }),
        el("div", { class: "small", text: `std (largest axis) ${fmt(largest(active.std_translation_mm))} mm, ${
          fmt(largest(active.std_rotation_deg), 3)} deg` }));
    }
    card.addEventListener("click", () => selectScanner(state.selected === s.name ? null : s.name));
    card.addEventListener("keydown", (e) => { if (e.key === "Enter" || e.key === " ") card.click(); });
    return card;
  }));
}

/** The history's scanner chooser: every scanner, or one. */
function renderScannerFilter() {
  const names = [null, ...state.status.scanners.map((s) => s.name)];
  $("scanner-filter").replaceChildren("Scanner: ", ...names.map((name) => {
    const button = el("button", { type: "button", class: state.selected === name ? "selected" : "",
                                  "data-scanner": name || "", text: name || "every scanner" });
    button.addEventListener("click", () => selectScanner(name));
    return button;
  }));
}

/** Show scanner ``name`` (null: every scanner) in the history, its exports and the scan picture. */
async function selectScanner(name) {
  state.selected = name;
  state.exports = null;
  $("start-verify").textContent = name ? `Start verify (${name})` : "Start verify";
  markDirty("status", "history", "scan");
  if (!name) return;
  try {
    state.exports = await api("GET", `/v1/calibration?scanner=${encodeURIComponent(name)}`);
  } catch (err) {
    state.exports = { missing: err.status === 404 ? `${name} has no active calibration` : err.message };
  }
  if (state.selected === name) markDirty("history");
}

/** The chosen scanner's active calibration as a ROS static transform and a URDF joint. */
function renderExports() {
  const node = $("exports");
  const exports = state.exports;
  node.hidden = !state.selected || !exports;
  if (node.hidden) return;
  if (exports.missing) {
    node.replaceChildren(el("span", { class: "muted", text: exports.missing }));
    return;
  }
  const args = exports.exports.static_transform_publisher_args;
  node.replaceChildren(
    el("div", {}, `Exports of ${state.selected}'s active calibration `, el("span", { class: "mono", text: exports.id }),
      ` (frame ${args[args.length - 1]}):`),
    el("pre", { class: "mono", "data-export": "static_transform_publisher",
                text: "ros2 run tf2_ros static_transform_publisher " + args.join(" ") }),
    el("pre", { class: "mono", "data-export": "urdf_joint", text: exports.exports.urdf_joint }));
}

async function refreshStatus() {
  try {
    [state.status, state.health] = await Promise.all([api("GET", "/v1/status"), api("GET", "/v1/health")]);
    const job = state.status.job;
    if (job && (!state.job || job.id === state.job.id || ACTIVE_STATES.has(job.state))) takeSnapshot(job);
    markDirty("status", "job");
  } catch (err) {
    showError(`cannot read the daemon's status: ${err.message}`);
  }
}

// ---- run panel ----------------------------------------------------------------------------

function adoptJob(job) {
  if (state.live.jobId !== job.id) state.live = freshLive(job.id);
  state.job = job;
}

/** A job record read from the daemon; the event stream may be ahead of it (a final state). */
function takeSnapshot(job) {
  const streamState = state.live.jobId === job.id && state.job ? state.job.state : null;
  const behind = ACTIVE_STATES.has(job.state) && streamState && !ACTIVE_STATES.has(streamState);
  adoptJob({ ...job, state: behind ? streamState : job.state });
}

function renderJob() {
  const job = state.job;
  const live = state.live;
  $("cancel-job").disabled = !(job && ACTIVE_STATES.has(job.state));
  if (!job) return;
  $("job-title").textContent = `${job.kind} ${job.id}`;
  const jobState = $("job-state");
  jobState.textContent = job.state;
  jobState.className = "badge " + stateKind(job.state);
  const p = live.progress || job.progress || {};
  const total = p.waypoint_count || 0;
  const done = p.completed || 0;
  const bar = $("progress");
  bar.setAttribute("aria-valuemax", String(total));
  bar.setAttribute("aria-valuenow", String(done));
  $("progress-fill").style.width = total ? `${(100 * done) / total}%` : "0";
  const of = isCell() && p.scanner ? `${p.scanner}: ` : "";  // a cell job's scanners run one after the other
  $("progress-text").textContent = total ? `${of}waypoint ${Math.min(done + (ACTIVE_STATES.has(job.state) && done < total ? 1 : 0), total)} of ${total} · ${done} done` : "–";
  $("time-left").textContent = ACTIVE_STATES.has(job.state) && p.time_left_s !== null && p.time_left_s !== undefined
    ? `about ${Math.round(p.time_left_s)} s left` : "";
  $("job-message").textContent = (job.error && job.error.message) || p.message || "";
  renderSkipped();
  renderResult();
}

function renderSkipped() {
  const list = $("skipped");
  const skipped = state.live.skipped;
  if (!skipped.length) {
    list.replaceChildren(el("li", { class: "muted", text: "none" }));
    return;
  }
  list.replaceChildren(...skipped.map((s) => el("li", {
    text: `${isCell() && s.scanner ? s.scanner + " " : ""}waypoint ${s.waypoint}: ${s.reason}` })));
}

/** Each scanner's result of the run (a cell job's one after the other), and its calibration's files. */
function renderResult() {
  const node = $("job-result");
  const job = state.job;
  const ids = calibrationIds(job);
  const cell = isCell();
  const names = [...new Set([...state.live.results.keys(), ...Object.keys(ids)])];
  node.replaceChildren(...names.map((name, i) => {
    const result = state.live.results.get(name);
    const part = el("div", { class: "scanner-result", "data-scanner": name });
    if (cell) part.append(el("span", { class: "mono name", text: name }), " ");
    if (result) {
      part.append(badge(result.passed ? "passed" : "failed the quality gates", result.passed ? "ok" : "bad"), " ",
        `RMS residual ${fmt(result.rms_residual_mm)} mm · std (largest axis) ${
          fmt(largest(result.std_translation_mm))} mm, ${fmt(largest(result.std_rotation_deg), 3)} deg`,
        el("div", { class: "mono pose", id: i === 0 ? "job-pose" : `job-pose-${name}`, text: poseText(result.T_base_laser) }));
    }
    const calibration = ids[name] && state.calibrations.find((c) => c.id === ids[name]);
    if (calibration) part.append(el("div", { class: "small files" }, "files: ", ...fileLinks(calibration.files)));
    return part;
  }));
}

/** The calibrations a job filed, by scanner (a cell job's document lists them all). */
function calibrationIds(job) {
  if (!job || !job.calibration_id) return {};
  return (job.document && job.document.calibration_ids) || { default: job.calibration_id };
}

function fileLinks(files) {
  return Object.entries(files || {}).map(([name, url]) => el("a", { href: url, target: "_blank", text: name }));
}

function renderLog() {
  const log = state.live.log;
  $("event-log").replaceChildren(...log.slice(-EVENT_LOG_LINES).reverse().map((line) => el("li", { text: line })));
}

// ---- scan picture -------------------------------------------------------------------------

/** Scan points (u, v) in metres in the scanner frame, and which are on the rod. */
function scanPoints(scan) {
  const points = [];
  scan.ranges_m.forEach((r, i) => {
    if (r === null || !Number.isFinite(r) || r <= 0) return;
    const a = scan.angle_min_rad + i * scan.angle_increment_rad;
    points.push([r * Math.cos(a), r * Math.sin(a), i]);
  });
  return points;
}

function renderScan() {
  const canvas = $("scan");
  const ctx = canvas.getContext("2d");
  const W = canvas.width;
  const H = canvas.height;
  ctx.clearRect(0, 0, W, H);
  const live = shownLive();
  const scan = live.scan;
  const rodBeams = new Set(scan ? scan.rod_beams : []);
  const points = scan ? scanPoints(scan) : [];
  const rodPoints = points.filter((p) => rodBeams.has(p[2]));
  const centres = [...live.centres.values()];
  const predicted = [...live.predicted.values()];
  // View: the scanner, every centre and the rod, with a margin (the far walls are clipped).
  const focus = [[0, 0], ...centres, ...predicted, ...rodPoints];
  if (scan && scan.circle) focus.push(scan.circle.centre_uv_m);
  // and the surroundings out to half as far again as the rod (walls beyond are clipped).
  const reach = 1.5 * Math.max(...focus.map(([u, v]) => Math.hypot(u, v)), 0.3);
  points.forEach(([u, v]) => { if (Math.hypot(u, v) <= reach) focus.push([u, v]); });
  let [minU, maxU, minV, maxV] = [Infinity, -Infinity, Infinity, -Infinity];
  focus.forEach(([u, v]) => { minU = Math.min(minU, u); maxU = Math.max(maxU, u); minV = Math.min(minV, v); maxV = Math.max(maxV, v); });
  const span = Math.max(maxU - minU, maxV - minV, 0.5) * 1.3;
  const midU = (minU + maxU) / 2;
  const midV = (minV + maxV) / 2;
  const scale = Math.min(W, H) / span;
  // u (scanner x) to the right, v (scanner y) up.
  const px = (u, v) => [W / 2 + (u - midU) * scale, H / 2 - (v - midV) * scale];

  ctx.font = "11px system-ui, sans-serif";
  const of = isCell() && live.name ? `${live.name}: ` : "";  // a cell's picture is of one scanner
  const caption = of + (scan ? `waypoint ${scan.waypoint}: ${rodBeams.size} beams on the rod` : "no scan yet");
  const captionBox = textBox(ctx, caption, 8, H - 8);
  drawGrid(ctx, W, H, px, midU, midV, span, [captionBox]);
  drawScanner(ctx, px);
  ctx.fillStyle = cssVar("--scan");
  points.forEach(([u, v, i]) => {
    if (rodBeams.has(i)) return;
    const [x, y] = px(u, v);
    if (x >= 0 && x <= W && y >= 0 && y <= H) ctx.fillRect(x - 1, y - 1, 2, 2);
  });
  ctx.fillStyle = cssVar("--rod");
  rodPoints.forEach(([u, v]) => { const [x, y] = px(u, v); ctx.fillRect(x - 2, y - 2, 4, 4); });
  if (scan && scan.circle) {
    const [x, y] = px(...scan.circle.centre_uv_m);
    ctx.strokeStyle = cssVar("--circle");
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.arc(x, y, Math.max(scan.circle.radius_m * scale, 6), 0, 2 * Math.PI);
    ctx.stroke();
  }
  predicted.forEach(([u, v]) => drawCross(ctx, ...px(u, v)));
  ctx.font = "11px system-ui, sans-serif";
  [...live.centres.entries()].forEach(([waypoint, [u, v]]) => {
    const [x, y] = px(u, v);
    ctx.fillStyle = cssVar("--measured");
    ctx.beginPath();
    ctx.arc(x, y, 4, 0, 2 * Math.PI);
    ctx.fill();
    ctx.fillText(String(waypoint), x + 6, y - 6);
  });
  if (scan && scan.circle) drawInset(ctx, W, scan, rodPoints);
  ctx.fillStyle = cssVar("--muted");
  ctx.font = "11px system-ui, sans-serif";
  ctx.fillText(caption, 8, H - 8);
  canvas.dataset.scans = String(state.live.scans);
  canvas.dataset.scanner = live.name || "";
  canvas.dataset.scannerScans = String(live.scans);
  canvas.dataset.waypoint = scan ? String(scan.waypoint) : "";
}

function cssVar(name) { return getComputedStyle(document.documentElement).getPropertyValue(name).trim(); }

/** The grid and its labels; a label that would overlap a text already placed (the caption,
 *  the axes, another label) is left out, and the canvas's data-overlapping-labels names any
 *  overlap that remains (the browser test fails on it). */
function drawGrid(ctx, W, H, px, midU, midV, span, placed) {
  const step = span > 4 ? 1 : span > 1.5 ? 0.5 : 0.1;
  ctx.strokeStyle = "#eef0f3";
  ctx.lineWidth = 1;
  ctx.fillStyle = cssVar("--muted");
  ctx.font = "10px system-ui, sans-serif";
  const axes = "u [m] →, v [m] ↑ (scan plane)";
  const axesX = W - ctx.measureText(axes).width - 8;
  placed.push(textBox(ctx, axes, axesX, H - 8));
  const label = (text, x, y) => {
    const box = textBox(ctx, text, x, y);
    if (placed.some((other) => boxesOverlap(box, other))) return;
    placed.push(box);
    ctx.fillText(text, x, y);
  };
  const u0 = Math.floor((midU - span) / step) * step;
  const v0 = Math.floor((midV - span) / step) * step;
  for (let u = u0; u <= midU + span; u += step) {
    const [x] = px(u, 0);
    ctx.beginPath(); ctx.moveTo(x, 0); ctx.lineTo(x, H); ctx.stroke();
    if (x < W - INSET_PX - 40) label(gridLabel(u), x + 2, 10);  // none under the close-up
  }
  for (let v = v0; v <= midV + span; v += step) {
    const [, y] = px(0, v);
    ctx.beginPath(); ctx.moveTo(0, y); ctx.lineTo(W, y); ctx.stroke();
    label(gridLabel(v), 2, y - 2);
  }
  ctx.fillText(axes, axesX, H - 8);
  const overlaps = placed.flatMap((a, i) => placed.slice(i + 1).filter((b) => boxesOverlap(a, b)).map((b) => `${a.text} / ${b.text}`));
  if (overlaps.length) ctx.canvas.dataset.overlappingLabels = overlaps.join("; ");
  else delete ctx.canvas.dataset.overlappingLabels;
}

/** The box a text drawn at (x, y) on its baseline covers, in the context's current font. */
function textBox(ctx, text, x, y) {
  const m = ctx.measureText(text);
  return { text, x0: x, x1: x + m.width, y0: y - m.actualBoundingBoxAscent, y1: y + m.actualBoundingBoxDescent };
}

function boxesOverlap(a, b) { return a.x0 < b.x1 && b.x0 < a.x1 && a.y0 < b.y1 && b.y0 < a.y1; }

function gridLabel(metres) { return (Math.abs(metres) < 1e-9 ? 0 : metres).toFixed(1); }

function drawScanner(ctx, px) {
  const [x, y] = px(0, 0);
  ctx.fillStyle = "#1d2330";
  ctx.beginPath();
  ctx.moveTo(x + 10, y); ctx.lineTo(x - 6, y - 7); ctx.lineTo(x - 6, y + 7);
  ctx.closePath();
  ctx.fill();
}

function drawCross(ctx, x, y) {
  ctx.strokeStyle = cssVar("--predicted");
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.moveTo(x - 5, y - 5); ctx.lineTo(x + 5, y + 5);
  ctx.moveTo(x + 5, y - 5); ctx.lineTo(x - 5, y + 5);
  ctx.stroke();
}

/** A close-up of the rod: its beams and the fitted circle, 8 radii across. */
function drawInset(ctx, W, scan, rodPoints) {
  const size = INSET_PX;
  const x0 = W - size - 8;
  const y0 = 8;
  const { centre_uv_m: [cu, cv], radius_m } = scan.circle;
  const scale = size / (8 * radius_m);
  const px = (u, v) => [x0 + size / 2 + (u - cu) * scale, y0 + size / 2 - (v - cv) * scale];
  ctx.fillStyle = "#fff";
  ctx.strokeStyle = cssVar("--line");
  ctx.lineWidth = 1;
  ctx.fillRect(x0, y0, size, size);
  ctx.strokeRect(x0, y0, size, size);
  ctx.save();
  ctx.beginPath(); ctx.rect(x0, y0, size, size); ctx.clip();
  ctx.strokeStyle = cssVar("--circle");
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.arc(...px(cu, cv), radius_m * scale, 0, 2 * Math.PI);
  ctx.stroke();
  ctx.fillStyle = cssVar("--rod");
  rodPoints.forEach(([u, v]) => { const [x, y] = px(u, v); ctx.fillRect(x - 2.5, y - 2.5, 5, 5); });
  ctx.restore();
  ctx.fillStyle = cssVar("--muted");
  const rodMm = (scan.rod_radius_m || radius_m) * 1000;
  const fitMm = radius_m * 1000;
  labelWithin(ctx, "rod close-up", x0 + 4, y0 + 14, size - 8);
  labelWithin(ctx, `rod r = ${rodMm.toFixed(1)} mm`, x0 + 4, y0 + size - 6, size - 8);
  if (Math.abs(fitMm - rodMm) >= 0.05) {
    labelWithin(ctx, `fit r = ${fitMm.toFixed(1)} mm`, x0 + 4, y0 + size - 20, size - 8);
  }
}

/** Draw a canvas label that must fit in ``maxWidth`` px; one that does not is named in the
 *  canvas's data-clipped-labels (the browser test fails on it) and squeezed to fit. */
function labelWithin(ctx, text, x, y, maxWidth) {
  const width = ctx.measureText(text).width;
  if (width > maxWidth) ctx.canvas.dataset.clippedLabels = `${text} (${Math.round(width)} > ${maxWidth} px)`;
  ctx.fillText(text, x, y, maxWidth);
}

// ---- history ------------------------------------------------------------------------------

async function refreshHistory() {
  try {
    const [calibrations, verifies] = await Promise.all([api("GET", "/v1/calibrations"), api("GET", "/v1/verifies")]);
    state.calibrations = calibrations.calibrations || [];
    state.verifies = verifies.verifies || [];
    // each calibration against its own scanner's active one
    await Promise.all(state.calibrations.map(async (c) => {
      const active = activeOf(c.scanner || "default");
      if (!active || c.id === active.id || state.diffs.has(`${c.id}:${active.id}`)) return;
      try { state.diffs.set(`${c.id}:${active.id}`, await api("GET", `/v1/calibrations/${c.id}/diff/${active.id}`)); }
      catch (err) { state.diffs.set(`${c.id}:${active.id}`, null); }
    }));
    if (state.selected) await selectScanner(state.selected);  // its active calibration may have changed
    markDirty("history", "status", "job");
  } catch (err) {
    showError(`cannot read the history: ${err.message}`);
  }
}

/** Rows of the history: calibrations and verifies (of the chosen scanner), newest first, each
 *  with its change against its scanner's active calibration. */
function historyRows() {
  const shown = (item) => !state.selected || (item.scanner || "default") === state.selected;
  const rows = state.calibrations.filter(shown).map((c) => {
    const active = activeOf(c.scanner || "default");
    let change = null;
    if (active && c.id === active.id) change = { t: [0, 0, 0], r: [0, 0, 0], st: c.std_translation_mm, sr: c.std_rotation_deg };
    const diff = active && state.diffs.get(`${c.id}:${active.id}`);
    if (diff) change = { t: diff.translation_mm, r: diff.rotation_deg, st: diff.combined_std_translation_mm,
                         sr: diff.combined_std_rotation_deg, significant: diff.significant };
    return { kind: c.dry_run ? "dry-run calibration" : "calibration", item: c, time: c.created_utc, change,
             result: badge(c.passed ? "passed" : "failed", c.passed ? "ok" : "bad"),
             std: `${fmt(largest(c.std_translation_mm))} / ${fmt(largest(c.std_rotation_deg), 3)}` };
  });
  state.verifies.filter(shown).forEach((v) => {
    const active = activeOf(v.scanner || "default");
    const against = v.calibration_id === (active && active.id) ? "" : ` (vs ${v.calibration_id})`;
    rows.push({ kind: "verify" + against, item: v, time: v.created_utc,
                change: { t: v.shift_translation_mm, r: v.shift_rotation_deg, st: v.shift_std_translation_mm,
                          sr: v.shift_std_rotation_deg },
                result: badge(v.verdict, { ok: "ok", degraded: "warn", inconclusive: "warn" }[v.verdict] || "bad"), std: "", reason: v.reason });
  });
  rows.sort((a, b) => Date.parse(b.time) - Date.parse(a.time));
  return rows;
}

function changeCell(d, std, digits) {
  if (!d) return el("td", { class: "muted", text: "–" });
  return el("td", { title: `components ${d.map((x) => fmt(x, digits)).join(", ")} ± ${(std || []).map((x) => fmt(x, digits)).join(", ")}`,
                    text: `${fmt(norm(d), digits)} ± ${fmt(normStd(d, std), digits)}` });
}

function renderHistory() {
  renderExports();
  if (state.status && isCell()) renderScannerFilter();
  const rows = historyRows();
  const body = $("history-body");
  if (!rows.length) {
    body.replaceChildren(el("tr", {}, el("td", { colspan: "9", class: "muted", text: "no calibrations yet" })));
  } else {
    body.replaceChildren(...rows.map((row) => {
      const item = row.item;
      const action = el("td");
      if (row.kind.endsWith("calibration")) {
        if (item.active) action.append(badge("active", "ok"));
        else if (item.bad) {
          action.append(el("span", { title: `marked bad by ${item.bad.by} ${utc(item.bad.time_utc)}: ${item.bad.reason}` },
            badge("bad", "bad")));
        } else {
          const button = el("button", { type: "button", class: "activate", "data-id": item.id, text: "Activate" });
          button.addEventListener("click", () => activate(item));
          action.append(button);
        }
      }
      const result = el("td", {}, row.result);
      if (row.reason) result.append(el("div", { class: "small muted", text: row.reason }));
      const tr = el("tr", { "data-id": item.id, "data-kind": row.kind, "data-scanner": item.scanner || "default",
                            class: item.active ? "active-row" : "" },
        el("td", { text: utc(row.time) }),
        el("td", { text: isCell() ? `${row.kind} · ${item.scanner || "default"}` : row.kind }),
        el("td", { class: "mono", text: item.id }),
        result, changeCell(row.change && row.change.t, row.change && row.change.st, 2),
        changeCell(row.change && row.change.r, row.change && row.change.sr, 3),
        el("td", { text: row.std }), el("td", { class: "files" }, ...fileLinks(item.files)), action);
      return tr;
    }));
  }
  renderDrift(rows.filter((r) => r.change));
}

/** Two strips over time: |Δ translation| [mm] and |Δ rotation| [deg], each with ±1 std bars. */
function renderDrift(rows) {
  const svg = $("drift");
  const NS = "http://www.w3.org/2000/svg";
  const node = (tag, attrs, text) => {
    const n = document.createElementNS(NS, tag);
    Object.entries(attrs).forEach(([k, v]) => n.setAttribute(k, v));
    if (text !== undefined) n.textContent = text;
    return n;
  };
  svg.replaceChildren();
  svg.setAttribute("viewBox", rows.length ? "0 0 900 260" : "0 0 900 40");
  if (!rows.length) {
    svg.append(node("text", { x: 20, y: 25 }, "no calibration to compare against yet: activate one"));
    return;
  }
  const times = rows.map((r) => Date.parse(r.time));
  let t0 = Math.min(...times);
  let t1 = Math.max(...times);
  if (t1 - t0 < 60000) { t0 -= 30000; t1 += 30000; }
  const [left, right, width] = [70, 880, 810];
  const x = (t) => left + ((t - t0) / (t1 - t0)) * (right - left);
  const strips = [
    { label: "Δ translation [mm]", top: 10, value: (r) => norm(r.change.t), std: (r) => normStd(r.change.t, r.change.st) },
    { label: "Δ rotation [deg]", top: 135, value: (r) => norm(r.change.r), std: (r) => normStd(r.change.r, r.change.sr) },
  ];
  strips.forEach((strip) => {
    const h = 95;
    const values = rows.map((r) => [strip.value(r) || 0, strip.std(r) || 0]);
    const top = Math.max(...values.map(([v, s]) => v + s), 1e-6) * 1.15;
    const y = (v) => strip.top + h - (v / top) * h;
    svg.append(node("line", { x1: left, x2: right, y1: y(0), y2: y(0), stroke: "#9aa4b2" }));
    svg.append(node("line", { x1: left, x2: left, y1: strip.top, y2: strip.top + h, stroke: "#9aa4b2" }));
    svg.append(node("text", { x: left + 6, y: strip.top + 10 }, strip.label));
    svg.append(node("text", { x: 4, y: y(top / 1.15) + 4 }, (top / 1.15).toPrecision(2)));
    svg.append(node("text", { x: 4, y: y(0) + 4 }, "0"));
    rows.forEach((r, i) => {
      const [v, s] = values[i];
      const cx = x(Date.parse(r.time));
      const colour = PLOT_COLOURS[plotKind(r)];
      svg.append(node("line", { x1: cx, x2: cx, y1: y(Math.max(v - s, 0)), y2: y(v + s), stroke: colour, "stroke-width": 1.5 }));
      svg.append(node("line", { x1: cx - 4, x2: cx + 4, y1: y(v + s), y2: y(v + s), stroke: colour }));
      const mark = node("circle", { cx, cy: y(v), r: 4, fill: colour });
      mark.append(node("title", {}, `${r.kind} ${r.item.id} ${utc(r.time)}: ${fmt(v, 3)} ± ${fmt(s, 3)}`));
      svg.append(mark);
    });
  });
  svg.append(node("text", { x: left, y: 255 }, utc(new Date(t0).toISOString())));
  svg.append(node("text", { x: right, y: 255, "text-anchor": "end" }, utc(new Date(t1).toISOString())));
  const legend = node("g", { class: "legend" });
  let at = left + width / 2 - 170;
  Object.entries(PLOT_LABELS).forEach(([kind, label]) => {
    legend.append(node("circle", { cx: at, cy: 251, r: 4, fill: PLOT_COLOURS[kind], "data-kind": kind }));
    legend.append(node("text", { x: at + 8, y: 255, "data-kind": kind }, label));
    at += 8 + 7 * label.length + 14;
  });
  legend.append(node("text", { x: at, y: 255 }, "bars ±1 std"));
  svg.append(legend);
}

/** The marks of the drift plot: colour and legend label per kind of row, one table. */
const PLOT_COLOURS = { calibration: "#2b6cb0", verify: "#dd6b20", inconclusive: "#9aa4b2" };
const PLOT_LABELS = { calibration: "calibration", verify: "verify", inconclusive: "verify, inconclusive" };

function plotKind(row) {
  if (!row.kind.startsWith("verify")) return "calibration";
  return row.item.verdict === "inconclusive" ? "inconclusive" : "verify";
}

// ---- live events --------------------------------------------------------------------------

const EVENT_KINDS = ["stage", "progress", "centre", "skip", "scan", "fault", "result", "state",
                     "confirmed", "warning", "stopped", "daemon", "calibration_marked_bad", "deactivation",
                     "pair_agreement"];

/** The daemon's events from now on, and the latest job's from its start (a reload mid-run). */
function connectEvents() {
  const latest = state.status && state.status.job;
  const since = latest && latest.created_utc ? `?since=${encodeURIComponent(latest.created_utc)}` : "";
  const source = new EventSource(`/v1/events${since}`);
  const streamState = $("stream-state");
  source.onopen = () => { streamState.textContent = "stream: live"; streamState.className = "badge ok"; };
  source.onerror = () => { streamState.textContent = "stream: reconnecting"; streamState.className = "badge warn"; };
  EVENT_KINDS.forEach((kind) => source.addEventListener(kind, (message) => onEvent(kind, message)));
}

function onEvent(kind, message) {
  const arrival = epochMs();
  let data;
  try { data = JSON.parse(message.data); } catch (_) { return; }
  const record = { id: message.lastEventId, kind, job_id: data.job_id || null, stage: data.stage || null,
                   waypoint: data.waypoint ?? null, completed: data.completed ?? null,
                   event_time_utc: data.time_utc || null, arrival_ms: arrival, render_ms: null, paint_ms: null };
  window.lasercalEvents.push(record);
  unpainted.push(record);
  if (data.job_id && data.job_id !== state.live.jobId) {
    // A stream replaying stored events brings older jobs too: only the latest job and new ones count.
    if (state.knownJobs.has(data.job_id)) return;
    const job = { id: data.job_id, kind: (state.job && state.job.id === data.job_id && state.job.kind) || "job",
                  state: "queued", progress: {} };
    adoptJob(job);
    refreshJob(data.job_id);
  }
  applyEvent(kind, data);
}

function applyEvent(kind, data) {
  const live = state.live;
  const job = state.job;
  const name = data.scanner || "default";  // a cell job's events name their scanner
  const scanner = ["scan", "centre"].includes(kind) ? scannerLive(name) : null;
  if (scanner || kind === "progress") live.current = name;
  const log = (text) => logLine(text, data.time_utc);
  switch (kind) {
    case "progress":
      live.progress = { waypoint: data.waypoint, completed: data.completed, waypoint_count: data.waypoint_count,
                        time_left_s: data.time_left_s, message: data.message || progressMessage(data),
                        scanner: data.scanner || null };
      log(`progress ${data.stage} ${data.completed}/${data.waypoint_count}`);
      markDirty("job", "log");
      break;
    case "stage":
      log(`stage ${data.stage}${data.message ? ": " + data.message : ""}`);
      markDirty("log");
      break;
    case "confirmed":
    case "warning":
    case "daemon":
    case "pair_agreement":  // a cell job's scanners against each other, once all are solved
      log(`${kind.replace(/_/g, " ")}: ${data.message || ""}`);
      markDirty("log");
      break;
    case "calibration_marked_bad":
    case "deactivation":
      log(`${kind.replace(/_/g, " ")}: ${data.calibration_id}${data.reason ? " (" + data.reason + ")" : ""}`);
      refreshHistory();
      refreshStatus();
      markDirty("log");
      break;
    case "stopped":
      log(`stopped: ${data.error || ""}${data.session ? " (recording kept: " + data.session + ")" : ""}`);
      markDirty("log");
      break;
    case "scan":
      scanner.scan = data;
      scanner.scans += 1;
      live.scans += 1;
      markDirty("scan");
      break;
    case "centre":
      scanner.centres.set(data.waypoint, data.centre_uv_m);
      if (data.predicted_uv_m || data.expected_uv_m) scanner.predicted.set(data.waypoint, data.predicted_uv_m || data.expected_uv_m);
      log(`centre ${data.waypoint}: (${fmt(data.centre_uv_m[0], 4)}, ${fmt(data.centre_uv_m[1], 4)}) m`);
      markDirty("scan", "log");
      break;
    case "skip":
      live.skipped.push({ waypoint: data.waypoint, reason: data.reason, scanner: data.scanner || null });
      log(`skip ${data.waypoint}: ${data.reason}`);
      markDirty("job", "log");
      break;
    case "fault":
      log(`fault ${data.device}: ${data.message}`);
      showError(`${data.device}: ${data.message}`);
      markDirty("log");
      break;
    case "result":
      live.results.set(name, data);
      log(`result: ${data.passed ? "passed" : "failed"}`);
      markDirty("job", "log");
      break;
    case "state":
      if (job) {
        job.state = data.state;
        if (data.error) job.error = data.error;
      }
      log(`state ${data.state}`);
      markDirty("job", "log");
      if (!ACTIVE_STATES.has(data.state)) finishJob(data.job_id);
      break;
    default:
      break;
  }
}

function progressMessage(data) {
  const where = data.waypoint === null || data.waypoint === undefined ? "" : ` waypoint ${data.waypoint}`;
  return `${data.stage}${where}`;
}

/** A line of the event log, stamped with the time the event happened (UTC). */
function logLine(text, timeUtc) {
  const log = state.live.log;
  log.push(`${(timeUtc || new Date().toISOString()).slice(11, 19)} ${text}`);
  if (log.length > EVENT_LOG_LINES) log.splice(0, log.length - EVENT_LOG_LINES);
}

async function refreshJob(jobId) {
  try {
    const job = await api("GET", `/v1/jobs/${jobId}`);
    if (state.live.jobId === jobId) {
      takeSnapshot(job);
      markDirty("job");
    }
  } catch (err) {
    showError(`cannot read job ${jobId}: ${err.message}`);
  }
}

/** After a job ends: its final record, the history, and the predicted centres from its result. */
async function finishJob(jobId) {
  await refreshJob(jobId);
  await Promise.all([refreshHistory(), refreshStatus()]);
  const job = state.job;
  if (!job || job.id !== jobId) return;
  await Promise.all(Object.entries(calibrationIds(job)).map(([name, id]) => showPredicted(name, id)));
}

/** The predicted centres of scanner ``name`` from its calibration's result. */
async function showPredicted(name, calibrationId) {
  const calibration = state.calibrations.find((c) => c.id === calibrationId);
  const resultUrl = calibration && calibration.files && calibration.files.result;
  if (!resultUrl) return;
  try {
    const result = await api("GET", resultUrl);
    const live = scannerLive(name);
    // Predicted centre = measured centre - residual (result.json residuals, mm).
    (result.residuals || []).forEach((r) => {
      const measured = live.centres.get(r.index);
      if (measured) live.predicted.set(r.index, [measured[0] - r.du_mm / 1000, measured[1] - r.dv_mm / 1000]);
    });
    markDirty("scan");
  } catch (err) {
    showError(`cannot read the result of ${calibrationId}: ${err.message}`);
  }
}

// ---- actions ------------------------------------------------------------------------------

async function startJob(kind) {
  showError("");
  const preset = $("preset").value;
  const dwell = Number($("dwell").value);
  const status = state.status || { daemon: {}, robot: {} };
  const where = kind === "dry_run" || status.daemon.dry_run
    ? "the fake cell (a dry run: no real arm moves)"
    : `the robot at ${status.robot.host || "the configured address"} — keep clear of the arm`;
  const scanner = kind === "verify" && isCell() ? state.selected : null;  // none chosen: the newest activation's
  const what = kind === "verify" ? `a verify run against the active calibration${scanner ? " of " + scanner : ""}`
    : isCell() ? "a dry-run calibration of every scanner" : "a dry-run calibration";
  // a verify runs the job recorded with the calibration it checks: the daemon refuses a job or dwell for it
  const how = kind === "verify" ? "the waypoints and dwell of the job recorded with that calibration"
    : `the ${preset} trajectory, dwelling ${dwell} s at every waypoint`;
  const ok = await confirmAction("Start motion?", `This starts ${what} on ${where}: ${how}.`, "Move the arm");
  if (!ok) return;
  const chosen = state.trajectories.find((t) => t.name === preset);
  const body = kind === "verify" ? { kind, confirm_motion: true }
    : { kind, confirm_motion: true, job: chosen ? chosen.job : { trajectory: { preset } }, dwell_s: dwell,
        activate_on_pass: $("activate-on-pass").checked };
  if (scanner) body.scanner = scanner;
  try {
    const job = await authorised("POST", "/v1/jobs", body);
    if (job) { takeSnapshot(job); markDirty("job"); }
  } catch (err) {
    showError(`${err.message} (${err.code})`);
  }
}

async function cancelJob() {
  const job = state.job;
  if (!job) return;
  const ok = await confirmAction("Cancel the run?", `Cancel ${job.kind} ${job.id}? The arm stops where it is; what was recorded is kept.`, "Cancel the run");
  if (!ok) return;
  try {
    const updated = await authorised("POST", `/v1/jobs/${job.id}/cancel`, {});
    if (updated && state.live.jobId === updated.id) {
      takeSnapshot(updated);
      markDirty("job");
    }
  } catch (err) {
    showError(`${err.message} (${err.code})`);
  }
}

async function activate(calibration) {
  const ok = await confirmAction("Activate calibration?",
    `Make ${calibration.id} (${utc(calibration.created_utc)}${calibration.dry_run ? ", dry run" : ""}) the active calibration${
      isCell() ? " of " + (calibration.scanner || "default") : ""}? Software reading the daemon's calibration picks it up.`,
    "Activate");
  if (!ok) return;
  try {
    if (await authorised("POST", `/v1/calibrations/${calibration.id}/activate`, {})) {
      await Promise.all([refreshHistory(), refreshStatus()]);
    }
  } catch (err) {
    showError(`${err.message} (${err.code})`);
  }
}

/** The jobs that existed when the page opened, but for the latest (whose events it shows). */
async function rememberJobs() {
  try {
    const jobs = (await api("GET", "/v1/jobs")).jobs || [];
    const latest = state.status && state.status.job ? state.status.job.id : null;
    jobs.forEach((job) => { if (job.id !== latest) state.knownJobs.add(job.id); });
  } catch (err) {
    showError(`cannot read the jobs: ${err.message}`);
  }
}

/** The trajectory list: every preset and designed waypoint file the daemon knows. */
async function loadTrajectories() {
  try {
    state.trajectories = (await api("GET", "/v1/trajectories")).trajectories || [];
  } catch (err) {
    showError(`cannot read the trajectories: ${err.message}`);
    return;
  }
  const select = $("preset");
  const current = select.value;
  select.replaceChildren(...state.trajectories.map((t) => el("option", {
    value: t.name, title: t.description,
    text: `${t.name} (${t.waypoints} waypoints${t.kind === "waypoints_file" ? ", designed" : ""})` })));
  if (state.trajectories.length && state.trajectories[0].kind === "cell") select.value = state.trajectories[0].name;
  else if (state.trajectories.some((t) => t.name === current)) select.value = current;
}

function init() {
  $("start-dry-run").addEventListener("click", () => startJob("dry_run"));
  $("start-verify").addEventListener("click", () => startJob("verify"));
  $("cancel-job").addEventListener("click", cancelJob);
  $("forget-token").addEventListener("click", () => { sessionStorage.removeItem(TOKEN_KEY); showError(""); });
  refreshHistory();
  loadTrajectories();
  refreshStatus().then(rememberJobs).then(connectEvents);
  setInterval(refreshStatus, STATUS_POLL_MS);
  markDirty("scan");
}

init();
