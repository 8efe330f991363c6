// fusion-pf annotate: the operator page. Plain JS, no dependencies.
// State lives on the server (SQLite); the page keeps the operator name in
// localStorage and the current frame in the URL hash (#frame=N).
"use strict";

const $ = (id) => document.getElementById(id);
const ZOOMS = [0.25, 0.33, 0.5, 0.67, 0.75, 1, 1.25, 1.5, 2, 3, 4, 6, 8];

const state = {
  info: null,          // /api/info
  operator: null,
  frame: 0,
  zoom: 1,
  fitted: true,        // zoom follows the window size until the user zooms
  done: new Map(),     // frame -> own click (this operator)
  view: null,          // /api/frames/<i>/clicks answer for the current frame
  color: null,         // HTMLImageElement of the current frame
  depth: null,         // HTMLImageElement of the depth overlay, or null
  token: 0,            // increments on every frame change; stale answers are dropped
};

function setStatus(text, isError = false) {
  const el = $("status");
  el.textContent = text;
  el.classList.toggle("error", isError);
}

async function api(path, options = {}) {
  const resp = await fetch(path, options);
  const body = await resp.json().catch(() => ({ error: `HTTP ${resp.status}` }));
  if (!resp.ok) throw new Error(body.error || `HTTP ${resp.status}`);
  return body;
}

function loadImage(src) {
  return new Promise((resolve, reject) => {
    const img = new Image();
    img.onload = () => resolve(img);
    img.onerror = () => reject(new Error(`cannot load ${src}`));
    img.src = src;
  });
}

function fmt(x) { return x.toFixed(1); }

// ---------------------------------------------------------------- operator

function askOperator(message = "") {
  const dialog = $("operator-dialog");
  $("operator-input").value = state.operator || "";
  $("operator-error").textContent = message;
  if (!dialog.open) dialog.showModal();
  $("operator-input").focus();
}

async function setOperator(name) {
  const clean = name.trim();
  const body = await api(`/api/operators/${encodeURIComponent(clean)}/clicks`);
  state.operator = body.operator;
  localStorage.setItem("fusion-pf-operator", state.operator);
  state.done = new Map(body.clicks.map((c) => [c.frame, c]));
  $("operator-label").textContent = state.operator;
  updateProgress();
  await showFrame(state.frame);
}

// ---------------------------------------------------------------- frames

function frameUrl(i, kind) { return `/api/frames/${i}/${kind}`; }

async function showFrame(index) {
  const n = state.info.n_frames;
  index = Math.max(0, Math.min(n - 1, index));
  const token = ++state.token;
  state.frame = index;
  history.replaceState(null, "", `#frame=${index}`);
  $("frame-label").textContent = `Frame ${index} / ${n}`;
  $("view").dataset.state = "loading";
  try {
    const wantDepth = $("depth-toggle").checked;
    const [meta, color, view] = await Promise.all([
      api(`${frameUrl(index, "meta")}`),
      loadImage(frameUrl(index, "color")),
      api(`/api/frames/${index}/clicks?operator=${encodeURIComponent(state.operator)}`),
    ]);
    let depth = null;
    if (wantDepth && meta.has_depth) depth = await loadImage(frameUrl(index, "depth"));
    if (token !== state.token) return;
    state.color = color;
    state.depth = depth;
    state.view = view;
    $("time-label").textContent = `t = ${((meta.timestamp_ns - state.info.start_ns) / 1e9).toFixed(3)} s`;
    if (state.fitted) fitZoom();
    render();
    setStatus(meta.has_depth || !wantDepth ? "" : "This frame has no depth image.");
    prefetch(index + 1);
  } catch (err) {
    if (token === state.token) setStatus(err.message, true);
  }
}

function prefetch(index) {
  if (index < state.info.n_frames) new Image().src = frameUrl(index, "color");
}

async function depthToggled() {
  await showFrame(state.frame);
}

// ---------------------------------------------------------------- drawing

function fitZoom() {
  const viewer = $("viewer");
  const w = state.color ? state.color.naturalWidth : state.info.width;
  const h = state.color ? state.color.naturalHeight : state.info.height;
  state.zoom = Math.max(0.1, Math.min((viewer.clientWidth - 16) / w, (viewer.clientHeight - 16) / h, 8));
}

function setZoom(z, fitted = false) {
  const viewer = $("viewer");
  const cx = (viewer.scrollLeft + viewer.clientWidth / 2) / state.zoom;
  const cy = (viewer.scrollTop + viewer.clientHeight / 2) / state.zoom;
  state.zoom = z;
  state.fitted = fitted;
  render();
  viewer.scrollLeft = cx * z - viewer.clientWidth / 2;
  viewer.scrollTop = cy * z - viewer.clientHeight / 2;
}

function zoomStep(dir) {
  const z = state.zoom;
  const next = dir > 0 ? ZOOMS.find((s) => s > z * 1.01) : [...ZOOMS].reverse().find((s) => s < z / 1.01);
  if (next !== undefined) setZoom(next);
}

function marker(ctx, u, v, z, style) {
  const x = (u + 0.5) * z, y = (v + 0.5) * z;
  ctx.save();
  if (style === "own") {
    ctx.strokeStyle = "#fff"; ctx.lineWidth = 4;
    ctx.beginPath(); ctx.arc(x, y, 8, 0, 2 * Math.PI); ctx.stroke();
    ctx.strokeStyle = "#e11d48"; ctx.lineWidth = 2;
    ctx.beginPath(); ctx.arc(x, y, 8, 0, 2 * Math.PI); ctx.stroke();
    ctx.beginPath(); ctx.moveTo(x - 13, y); ctx.lineTo(x - 4, y); ctx.moveTo(x + 4, y); ctx.lineTo(x + 13, y);
    ctx.moveTo(x, y - 13); ctx.lineTo(x, y - 4); ctx.moveTo(x, y + 4); ctx.lineTo(x, y + 13); ctx.stroke();
  } else if (style === "other") {
    ctx.fillStyle = "#0891b2"; ctx.strokeStyle = "#fff"; ctx.lineWidth = 1.5;
    ctx.beginPath(); ctx.arc(x, y, 4, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
  } else {
    ctx.strokeStyle = "#111"; ctx.lineWidth = 5;
    ctx.beginPath(); ctx.moveTo(x - 7, y - 7); ctx.lineTo(x + 7, y + 7); ctx.moveTo(x + 7, y - 7); ctx.lineTo(x - 7, y + 7); ctx.stroke();
    ctx.strokeStyle = "#f59e0b"; ctx.lineWidth = 2.5; ctx.stroke();
  }
  ctx.restore();
}

function render() {
  const canvas = $("view");
  const img = state.color;
  if (!img) return;
  const z = state.zoom;
  canvas.width = Math.round(img.naturalWidth * z);
  canvas.height = Math.round(img.naturalHeight * z);
  const ctx = canvas.getContext("2d");
  ctx.imageSmoothingEnabled = z < 1;
  ctx.drawImage(img, 0, 0, canvas.width, canvas.height);
  if (state.depth) {
    ctx.globalAlpha = Number($("depth-opacity").value);
    ctx.drawImage(state.depth, 0, 0, canvas.width, canvas.height);
    ctx.globalAlpha = 1;
  }
  const view = state.view;
  if (view && view.others) {
    for (const c of view.others) if (c.visible) marker(ctx, c.u, c.v, z, "other");
    const ref = view.reference;
    if (ref && ref.mean_u !== null && ref.n_operators > 1) marker(ctx, ref.mean_u, ref.mean_v, z, "mean");
  }
  if (view && view.own && view.own.visible) marker(ctx, view.own.u, view.own.v, z, "own");
  $("zoom-label").textContent = `${Math.round(z * 100)}%`;
  renderSidebar();
  canvas.dataset.frame = String(state.frame);
  canvas.dataset.state = "ready";
}

function renderSidebar() {
  const view = state.view;
  const own = view && view.own;
  const ownEl = $("own-click");
  ownEl.textContent = !own ? "not done yet — click the palm centre"
    : own.visible ? `(${fmt(own.u)}, ${fmt(own.v)})` : "not visible";
  ownEl.classList.toggle("done", Boolean(own));
  const list = $("others");
  list.replaceChildren();
  $("others-hidden").hidden = Boolean(view && view.others);
  $("ref-label").textContent = "";
  if (view && view.others) {
    if (view.others.length === 0) {
      $("ref-label").textContent = "Nobody else has done this frame yet.";
    }
    for (const c of view.others) {
      const li = document.createElement("li");
      const name = document.createElement("span");
      name.textContent = c.operator;
      const pos = document.createElement("span");
      pos.textContent = c.visible ? `(${fmt(c.u)}, ${fmt(c.v)})` : "not visible";
      li.append(name, pos);
      list.append(li);
    }
    const ref = view.reference;
    if (view.others.length && ref.mean_u !== null) {
      $("ref-label").textContent =
        `Mean of ${ref.n_operators - ref.n_not_visible}: (${fmt(ref.mean_u)}, ${fmt(ref.mean_v)}), spread ${fmt(ref.spread_px)} px`;
    }
  }
  drawTimeline();
}

function updateProgress() {
  const n = state.info.n_frames;
  $("progress-label").textContent = `${state.done.size} of ${n} done`;
  $("progress-bar").max = n;
  $("progress-bar").value = state.done.size;
  drawTimeline();
}

function drawTimeline() {
  const canvas = $("timeline");
  const n = state.info.n_frames;
  canvas.width = canvas.clientWidth || 270;
  const ctx = canvas.getContext("2d");
  const w = canvas.width / n;
  ctx.fillStyle = "#e5e7eb";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = "#16a34a";
  for (const f of state.done.keys()) ctx.fillRect(f * w, 0, Math.max(w, 1), canvas.height);
  ctx.fillStyle = "#1d2330";
  ctx.fillRect(state.frame * w, 0, Math.max(w, 2), canvas.height);
}

// ---------------------------------------------------------------- clicks

async function sendClick(u, v) {
  const frame = state.frame;
  const token = state.token;
  try {
    const view = await api("/api/clicks", {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ operator: state.operator, frame, u, v }),
    });
    state.done.set(frame, view.own);
    updateProgress();
    if (token === state.token) {
      state.view = view;
      render();
      setStatus(view.own.visible ? `Saved frame ${frame}.` : `Saved frame ${frame} as not visible.`);
      if ($("auto-advance").checked && frame + 1 < state.info.n_frames) await showFrame(frame + 1);
    }
  } catch (err) {
    setStatus(`Not saved: ${err.message}`, true);
  }
}

function canvasClick(event) {
  if (!state.color || !state.operator) return;
  const rect = $("view").getBoundingClientRect();
  const w = state.color.naturalWidth, h = state.color.naturalHeight;
  const u = Math.max(-0.5, Math.min(w - 0.5, ((event.clientX - rect.left) / rect.width) * w - 0.5));
  const v = Math.max(-0.5, Math.min(h - 0.5, ((event.clientY - rect.top) / rect.height) * h - 0.5));
  sendClick(Math.round(u * 10) / 10, Math.round(v * 10) / 10);
}

function nextUndone() {
  const n = state.info.n_frames;
  for (let k = 1; k <= n; k++) {
    const f = (state.frame + k) % n;
    if (!state.done.has(f)) return showFrame(f);
  }
  setStatus("You have done every frame.");
}

// ---------------------------------------------------------------- wiring

function onKey(event) {
  if ($("operator-dialog").open || event.ctrlKey || event.metaKey || event.altKey) return;
  if (event.target instanceof HTMLInputElement && event.target.type !== "checkbox" && event.target.type !== "range") return;
  const actions = {
    ArrowLeft: () => showFrame(state.frame - 1),
    ArrowRight: () => showFrame(state.frame + 1),
    PageUp: () => showFrame(state.frame - 10),
    PageDown: () => showFrame(state.frame + 10),
    Home: () => showFrame(0),
    End: () => showFrame(state.info.n_frames - 1),
    n: nextUndone,
    x: () => sendClick(null, null),
    d: () => { $("depth-toggle").checked = !$("depth-toggle").checked; depthToggled(); },
    a: () => { $("auto-advance").checked = !$("auto-advance").checked; },
    "+": () => zoomStep(1),
    "=": () => zoomStep(1),
    "-": () => zoomStep(-1),
    "0": () => { fitZoom(); setZoom(state.zoom, true); },
  };
  const action = actions[event.key];
  if (action) {
    event.preventDefault();
    action();
  }
}

async function main() {
  state.info = await api("/api/info");
  $("recording").textContent = state.info.recording;
  const m = /#frame=(\d+)/.exec(location.hash);
  state.frame = m ? Math.min(Number(m[1]), state.info.n_frames - 1) : 0;
  $("operator-input").maxLength = state.info.max_operator_len;

  $("operator-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    try {
      await setOperator($("operator-input").value);
      $("operator-dialog").close();
    } catch (err) {
      $("operator-error").textContent = err.message;
    }
  });
  $("operator-dialog").addEventListener("cancel", (event) => { if (!state.operator) event.preventDefault(); });
  $("change-operator").addEventListener("click", () => askOperator());
  $("view").addEventListener("click", canvasClick);
  $("prev").addEventListener("click", () => showFrame(state.frame - 1));
  $("next").addEventListener("click", () => showFrame(state.frame + 1));
  $("next-undone").addEventListener("click", nextUndone);
  $("not-visible").addEventListener("click", () => sendClick(null, null));
  $("zoom-in").addEventListener("click", () => zoomStep(1));
  $("zoom-out").addEventListener("click", () => zoomStep(-1));
  $("zoom-fit").addEventListener("click", () => { fitZoom(); setZoom(state.zoom, true); });
  $("depth-toggle").addEventListener("change", depthToggled);
  $("depth-opacity").addEventListener("input", render);
  $("timeline").addEventListener("click", (event) => {
    const rect = $("timeline").getBoundingClientRect();
    showFrame(Math.floor(((event.clientX - rect.left) / rect.width) * state.info.n_frames));
  });
  window.addEventListener("resize", () => { if (state.fitted) { fitZoom(); render(); } });
  document.addEventListener("keydown", onKey);
  // Buttons keep focus after a mouse click; blur them so keys never re-press them.
  document.addEventListener("mouseup", () => {
    if (document.activeElement instanceof HTMLButtonElement) document.activeElement.blur();
  });

  const saved = localStorage.getItem("fusion-pf-operator");
  if (saved) {
    try {
      await setOperator(saved);
      return;
    } catch (err) {
      askOperator(err.message);
      return;
    }
  }
  askOperator();
}

main().catch((err) => setStatus(`Cannot start: ${err.message}`, true));
