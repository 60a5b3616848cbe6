// graphsvc report viewer: draws the reconstruction (and the truth) as skeletons with
// three.js, and time-aligned charts of errors, sensor readings, the source timeline
// and the constraints. Reads the JSON blob in #graphsvc-data (graphsvc/report/gather.py).
// Test hook: window.graphsvcViewer.
(function () {
  "use strict";
  const DATA = JSON.parse(document.getElementById("graphsvc-data").textContent);
  const COLORS = { reconstruction: 0x1f6fd1, truth: 0x2a9d3a };
  const KIND_COLORS = { original: "#8fb3de", speed: "#f2b134", interpolated: "#b36ae2", bridge: "#e36b5d", blend: "#5fbfa8" };
  const SIDE_BY_SIDE_M = 1.5;
  const $ = (id) => document.getElementById(id);

  function decode(b64, Type) {
    const bin = atob(b64);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return new Type(bytes.buffer);
  }

  // ------------------------------------------------------------ one clip's arrays

  function prepareFigure(fig, T) {
    const J = fig.parents.length;
    const root = decode(fig.root_mm, Int32Array);
    const rel = decode(fig.rel_mm, Int16Array);
    const pos = new Float32Array(T * J * 3); // metres
    for (let t = 0; t < T; t++) {
      for (let j = 0; j < J; j++) {
        for (let c = 0; c < 3; c++) {
          pos[(t * J + j) * 3 + c] = (root[t * 3 + c] + rel[(t * J + j) * 3 + c]) / 1000;
        }
      }
    }
    // the joint followed (gather.py centre_joint: the pelvis) and the joints drawn (not a
    // root fixed above the pelvis)
    const centre = Number.isInteger(fig.centre) && fig.centre >= 0 && fig.centre < J ? fig.centre : 0;
    const drawn = Array.isArray(fig.drawn) ? fig.drawn.filter((j) => Number.isInteger(j) && j >= 0 && j < J)
      : Array.from({ length: J }, (_, j) => j);
    return { name: fig.name, J, parents: fig.parents, pos, contacts: fig.contacts, feet: fig.feet, centre, drawn };
  }

  // (x, z) of a figure's centre joint at frame t
  const centreX = (f, t) => f.pos[(t * f.J + f.centre) * 3];
  const centreZ = (f, t) => f.pos[(t * f.J + f.centre) * 3 + 2];

  function prepareSensors(s, T) {
    if (!s) return null;
    const conv = (b) => {
      const a = decode(b, Int16Array);
      const out = new Float32Array(a.length);
      for (let i = 0; i < a.length; i++) out[i] = a[i] === -32768 ? NaN : a[i] / 100;
      return out;
    };
    return { names: s.names, measured: s.measured.map(conv), virtual: s.virtual.map(conv) };
  }

  function prepareMarkers(m, T) {
    if (!m) return null;
    const a = decode(m.mm, Int32Array);
    const M = m.names.length;
    const out = new Float32Array(a.length);
    for (let i = 0; i < a.length; i++) out[i] = a[i] === -2147483648 ? NaN : a[i] / 1000;
    return { names: m.names, M, pos: out };
  }

  // ------------------------------------------------------------ the 3D scene

  const view = $("view");
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  view.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0xf4f5f7);
  const camera = new THREE.PerspectiveCamera(45, 2, 0.05, 500);
  let grid = new THREE.Object3D();
  grid.geometry = { dispose() {} };
  scene.add(grid);
  const orbit = { az: 0.6, el: 0.35, dist: 6, target: new THREE.Vector3(0, 0.9, 0) };

  let clip = null; // the loaded clip's state
  let objects = [];
  let frame = 0;
  let drawn = -1;
  let playing = false;
  let playTime = 0;
  let lastTick = null;

  function clearScene() {
    for (const o of objects) {
      scene.remove(o);
      if (o.geometry) o.geometry.dispose();
      if (o.material) o.material.dispose();
    }
    objects = [];
  }

  function add(o) {
    scene.add(o);
    objects.push(o);
    return o;
  }

  function buildFigure(fig, T) {
    const color = COLORS[fig.name] || 0x555555;
    // bones between drawn joints only: none from a root fixed above the pelvis
    const isDrawn = new Uint8Array(fig.J);
    for (const j of fig.drawn) isDrawn[j] = 1;
    const bones = [];
    for (const j of fig.drawn) if (fig.parents[j] >= 0 && isDrawn[fig.parents[j]]) bones.push(fig.parents[j], j);
    const segGeom = new THREE.BufferGeometry();
    segGeom.setAttribute("position", new THREE.BufferAttribute(new Float32Array(bones.length * 3), 3));
    const lines = add(new THREE.LineSegments(segGeom, new THREE.LineBasicMaterial({ color })));
    const ptGeom = new THREE.BufferGeometry();
    ptGeom.setAttribute("position", new THREE.BufferAttribute(new Float32Array(fig.drawn.length * 3), 3));
    const points = add(new THREE.Points(ptGeom, new THREE.PointsMaterial({ color, size: 0.045 })));
    const trailGeom = new THREE.BufferGeometry();
    const trail = new Float32Array(T * 3);
    for (let t = 0; t < T; t++) {
      trail[t * 3] = centreX(fig, t);
      trail[t * 3 + 1] = 0.004;
      trail[t * 3 + 2] = centreZ(fig, t);
    }
    trailGeom.setAttribute("position", new THREE.BufferAttribute(trail, 3));
    const trailLine = add(new THREE.Line(trailGeom, new THREE.LineBasicMaterial({ color, transparent: true, opacity: 0.55 })));
    const feet = [];
    for (let k = 0; k < 2; k++) {
      const m = new THREE.Mesh(new THREE.CircleGeometry(0.07, 20), new THREE.MeshBasicMaterial({ color: 0xd62828, side: THREE.DoubleSide }));
      m.rotation.x = -Math.PI / 2;
      feet.push(add(m));
    }
    return { fig, bones, lines, points, trailLine, feet, offset: 0 };
  }

  function buildMarkers(markers) {
    if (!markers) return null;
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(new Float32Array(markers.M * 3), 3));
    return add(new THREE.Points(g, new THREE.PointsMaterial({ color: 0xff7f0e, size: 0.1 })));
  }

  // the ground grid under every figure's trail (its centre joint's), 1 m squares
  function placeGrid() {
    let x0 = Infinity, x1 = -Infinity, z0 = Infinity, z1 = -Infinity;
    for (const f of clip.figures) {
      for (let t = 0; t < clip.T; t++) {
        const x = centreX(f, t), z = centreZ(f, t);
        x0 = Math.min(x0, x); x1 = Math.max(x1, x); z0 = Math.min(z0, z); z1 = Math.max(z1, z);
      }
    }
    const half = Math.ceil(Math.max(x1 - x0, z1 - z0) / 2 + 4);
    scene.remove(grid);
    grid.geometry.dispose();
    // 1 m pieces, not lines across the whole floor: a software renderer drops a long
    // line that passes behind the camera
    const v = [];
    for (let a = -half; a <= half; a++) {
      for (let b = -half; b < half; b++) v.push(a, 0, b, a, 0, b + 1, b, 0, a, b + 1, 0, a);
    }
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(new Float32Array(v), 3));
    grid = new THREE.LineSegments(g, new THREE.LineBasicMaterial({ color: 0xb3bac2 }));
    grid.position.set(Math.round((x0 + x1) / 2), 0, Math.round((z0 + z1) / 2));
    scene.add(grid);
  }

  function layoutOffsets() {
    const side = $("layout").value === "side";
    clip.drawn.forEach((d, k) => {
      d.offset = side && k > 0 ? SIDE_BY_SIDE_M * k : 0;
      d.trailLine.position.x = d.offset;
    });
  }

  function drawFrame(i) {
    for (const d of clip.drawn) {
      const { fig, bones } = d;
      const base = i * fig.J * 3;
      const seg = d.lines.geometry.attributes.position.array;
      for (let b = 0; b < bones.length; b++) {
        const j = bones[b];
        seg[b * 3] = fig.pos[base + j * 3] + d.offset;
        seg[b * 3 + 1] = fig.pos[base + j * 3 + 1];
        seg[b * 3 + 2] = fig.pos[base + j * 3 + 2];
      }
      d.lines.geometry.attributes.position.needsUpdate = true;
      d.lines.geometry.computeBoundingSphere();
      const pts = d.points.geometry.attributes.position.array;
      fig.drawn.forEach((j, k) => {
        pts[k * 3] = fig.pos[base + j * 3] + d.offset;
        pts[k * 3 + 1] = fig.pos[base + j * 3 + 1];
        pts[k * 3 + 2] = fig.pos[base + j * 3 + 2];
      });
      d.points.geometry.attributes.position.needsUpdate = true;
      d.points.geometry.computeBoundingSphere();
      d.trailLine.geometry.setDrawRange(0, i + 1);
      for (let k = 0; k < 2; k++) {
        const on = fig.contacts && fig.contacts[k][i] === "1";
        d.feet[k].visible = !!on;
        if (on) {
          const j = fig.feet[k];
          d.feet[k].position.set(fig.pos[base + j * 3] + d.offset, 0.006, fig.pos[base + j * 3 + 2]);
        }
      }
    }
    if (clip.markerPoints) {
      const M = clip.markers.M;
      const arr = clip.markerPoints.geometry.attributes.position.array;
      for (let m = 0; m < M * 3; m++) {
        const v = clip.markers.pos[i * M * 3 + m];
        arr[m] = isNaN(v) ? 1e6 : v;
      }
      clip.markerPoints.geometry.attributes.position.needsUpdate = true;
      clip.markerPoints.geometry.computeBoundingSphere();
    }
    if ($("follow").checked) { // the middle of the figures' centre joints
      let x = 0, z = 0;
      for (const e of clip.drawn) {
        x += centreX(e.fig, i) + e.offset;
        z += centreZ(e.fig, i);
      }
      orbit.target.set(x / clip.drawn.length, 0.9, z / clip.drawn.length);
    }
    placeCamera();
    renderer.render(scene, camera);
    drawn = i;
    const t = i / clip.rate;
    $("frame-number").textContent = `frame ${i} / ${clip.T - 1}`;
    $("frame-time").textContent = `${t.toFixed(2)} s`;
    $("scrub").value = String(i);
    $("frame-info").textContent = frameInfo(i);
    drawCursors(i);
  }

  function placeCamera() {
    const { az, el, dist, target } = orbit;
    camera.position.set(target.x + dist * Math.cos(el) * Math.sin(az), target.y + dist * Math.sin(el),
      target.z + dist * Math.cos(el) * Math.cos(az));
    camera.lookAt(target);
  }

  function resize() {
    const w = view.clientWidth || 800;
    const h = view.clientHeight || 420;
    renderer.setSize(w, h);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
    if (clip) {
      drawCharts();
      drawFrame(frame);
    }
  }

  // orbit: drag to turn, wheel to zoom
  let drag = null;
  renderer.domElement.addEventListener("pointerdown", (e) => { drag = { x: e.clientX, y: e.clientY }; });
  window.addEventListener("pointerup", () => { drag = null; });
  window.addEventListener("pointermove", (e) => {
    if (!drag || !clip) return;
    orbit.az -= (e.clientX - drag.x) * 0.008;
    orbit.el = Math.max(-0.2, Math.min(1.45, orbit.el + (e.clientY - drag.y) * 0.006));
    drag = { x: e.clientX, y: e.clientY };
    drawFrame(frame);
  });
  renderer.domElement.addEventListener("wheel", (e) => {
    e.preventDefault();
    orbit.dist = Math.max(1, Math.min(80, orbit.dist * Math.exp(e.deltaY * 0.001)));
    if (clip) drawFrame(frame);
  }, { passive: false });

  // ------------------------------------------------------------ charts

  const charts = {};

  function chartCanvas(id, height) {
    const c = $(id);
    c.width = c.parentElement.clientWidth || 800;
    c.height = height;
    return c;
  }

  const PAD_L = 150, PAD_R = 10;
  const xOf = (c, i) => PAD_L + (c.width - PAD_L - PAD_R) * (clip.T > 1 ? i / (clip.T - 1) : 0);
  const frameAt = (c, x) => Math.max(0, Math.min(clip.T - 1, Math.round((x - PAD_L) / (c.width - PAD_L - PAD_R) * (clip.T - 1))));

  function finishChart(id, c) {
    const snap = document.createElement("canvas");
    snap.width = c.width;
    snap.height = c.height;
    snap.getContext("2d").drawImage(c, 0, 0);
    charts[id] = { canvas: c, snap };
  }

  function drawLines(ctx, c, series, top, height, unit) {
    let lo = Infinity, hi = -Infinity;
    for (const s of series) for (const v of s.values) if (Number.isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    if (!Number.isFinite(lo)) { lo = 0; hi = 1; }
    if (hi - lo < 1e-9) { hi = lo + 1; }
    const y = (v) => top + height - (v - lo) / (hi - lo) * height;
    ctx.strokeStyle = "#ccd";
    ctx.strokeRect(PAD_L, top, c.width - PAD_L - PAD_R, height);
    ctx.fillStyle = "#555";
    ctx.font = "11px sans-serif";
    ctx.fillText(`${hi.toFixed(1)} ${unit}`, PAD_L - 70, top + 10);
    ctx.fillText(`${lo.toFixed(1)} ${unit}`, PAD_L - 70, top + height);
    series.forEach((s, k) => {
      ctx.strokeStyle = s.color;
      ctx.setLineDash(s.dash || []);
      ctx.beginPath();
      let pen = false;
      for (let i = 0; i < s.values.length; i++) {
        const v = s.values[i];
        if (!Number.isFinite(v)) { pen = false; continue; }
        if (pen) ctx.lineTo(xOf(c, i), y(v)); else ctx.moveTo(xOf(c, i), y(v));
        pen = true;
      }
      ctx.stroke();
      ctx.setLineDash([]);
      ctx.fillStyle = s.color;
      ctx.fillText(s.label, 6, top + 12 + 13 * k);
    });
  }

  function drawErrors() {
    const box = $("errors-box");
    if (!clip.errors) { box.style.display = "none"; return; }
    box.style.display = "";
    const keys = [["joint_err_cm", "joint cm", "#1f6fd1"], ["root_err_cm", "root cm", "#e36b5d"], ["heading_err_deg", "heading °", "#2a9d3a"]];
    const rows = keys.filter(([k]) => clip.errors[k]);
    const c = chartCanvas("errors", 64 * rows.length + 8);
    const ctx = c.getContext("2d");
    rows.forEach(([k, label, color], r) => drawLines(ctx, c, [{ values: clip.errors[k], color, label }], 4 + r * 64, 56, label.split(" ")[1]));
    finishChart("errors", c);
  }

  function drawSensors() {
    const box = $("sensors-box");
    const s = clip.sensors;
    if (!s) { box.style.display = "none"; return; }
    box.style.display = "";
    const pick = $("sensor");
    if (pick.options.length !== s.names.length || pick.dataset.clip !== String(clip.index)) {
      pick.innerHTML = "";
      s.names.forEach((n, k) => pick.add(new Option(n, String(k))));
      pick.dataset.clip = String(clip.index);
    }
    const k = Number(pick.value || 0);
    const c = chartCanvas("sensors", 3 * 70 + 8);
    const ctx = c.getContext("2d");
    const T = clip.T;
    ["x", "y", "z"].forEach((axis, a) => {
      const m = new Float32Array(T), v = new Float32Array(T);
      for (let t = 0; t < T; t++) { m[t] = s.measured[k][t * 3 + a]; v[t] = s.virtual[k][t * 3 + a]; }
      drawLines(ctx, c, [{ values: v, color: "rgba(31,111,209,0.9)", label: `${axis} path` }, { values: m, color: "rgba(40,40,40,0.8)", label: `${axis} measured` }], 4 + a * 70, 62, "m/s²");
    });
    finishChart("sensors", c);
  }

  function hashColor(s) {
    let h = 0;
    for (let i = 0; i < s.length; i++) h = (h * 31 + s.charCodeAt(i)) >>> 0;
    return `hsl(${h % 360},55%,68%)`;
  }

  // The prefix every clip name of a list shares, up to and including its last separator
  // ("dataset-2_" of every Bandai-Namco clip): "" for fewer than two distinct names.
  function commonPrefix(names) {
    const distinct = [...new Set(names.filter((n) => typeof n === "string" && n))];
    if (distinct.length < 2) return "";
    let p = distinct[0];
    for (const n of distinct) {
      let k = 0;
      while (k < p.length && k < n.length && p[k] === n[k]) k++;
      p = p.slice(0, k);
    }
    let cut = -1;
    for (const sep of "_- ./") cut = Math.max(cut, p.lastIndexOf(sep));
    return p.slice(0, cut + 1);
  }

  const unprefixed = (name, prefix) =>
    (prefix && name.startsWith(prefix) && name.length > prefix.length ? name.slice(prefix.length) : name);

  // `text` cut in the middle ("walk-tu…_002") to fit `width` px; "" when not even two
  // characters do
  function fitText(ctx, text, width) {
    if (ctx.measureText(text).width <= width) return text;
    const cut = (n) => text.slice(0, Math.ceil(n / 2)) + "…" + text.slice(text.length - Math.floor(n / 2));
    let lo = 2, hi = text.length - 1; // (the most characters kept that fit)
    if (ctx.measureText(cut(lo)).width > width) return "";
    while (lo < hi) {
      const mid = Math.ceil((lo + hi) / 2);
      if (ctx.measureText(cut(mid)).width <= width) lo = mid; else hi = mid - 1;
    }
    return cut(lo);
  }

  function drawTimeline() {
    const tl = clip.timeline;
    const nb = tl.neighbours;
    const rows = 2 + (nb ? nb.clips.length : 0);
    const c = chartCanvas("timeline", rows * 22 + 8);
    const ctx = c.getContext("2d");
    ctx.font = "11px sans-serif";
    // clip names without the prefix they all share, cut in the middle where they do not
    // fit (the full name: hover, or the line under the chart)
    const prefix = commonPrefix([...tl.segments.map((s) => s.clip), ...(nb ? nb.clips : [])]);
    const row = (r, name) => { ctx.fillStyle = "#555"; ctx.fillText(name, 6, 4 + r * 22 + 14); return 4 + r * 22; };
    let y = row(0, "source clips");
    for (const s of tl.segments) {
      const x0 = xOf(c, s.start), x1 = xOf(c, Math.min(clip.T - 1, s.start + s.frames));
      ctx.fillStyle = KIND_COLORS[s.kind] || "#999";
      ctx.fillRect(x0, y, Math.max(1, x1 - x0), 18);
      const text = s.clip ? fitText(ctx, unprefixed(s.clip, prefix), x1 - x0 - 4) : "";
      if (text) { ctx.fillStyle = "#222"; ctx.fillText(text, x0 + 2, y + 13); }
    }
    ctx.fillStyle = "#222";
    for (const t of tl.transitions) ctx.fillRect(xOf(c, t), y - 2, 1, 22);
    y = row(1, "labels");
    for (const r of tl.labels) {
      const x0 = xOf(c, r.start_frame), x1 = xOf(c, Math.min(clip.T - 1, r.start_frame + r.frames));
      ctx.fillStyle = hashColor(r.label);
      ctx.fillRect(x0, y, Math.max(1, x1 - x0), 18);
      const text = fitText(ctx, r.label, x1 - x0 - 4);
      if (text) { ctx.fillStyle = "#222"; ctx.fillText(text, x0 + 2, y + 13); }
    }
    if (nb) {
      nb.clips.forEach((name, k) => {
        const yy = row(2 + k, fitText(ctx, unprefixed(name, prefix), PAD_L - 12));
        const w = nb.weights[k];
        for (let t = 0; t < clip.T; t++) {
          const v = w.charCodeAt(t) - 48;
          if (v <= 0) continue;
          ctx.fillStyle = `rgba(95,191,168,${v / 9})`;
          ctx.fillRect(xOf(c, t), yy, Math.max(1, xOf(c, t + 1) - xOf(c, t)), 18);
        }
      });
    }
    finishChart("timeline", c);
    const legend = Object.entries(KIND_COLORS).map(([k, col]) => `<span class="sw" style="background:${col}"></span>${k}`).join(" ");
    $("timeline-legend").innerHTML = legend + ' <span class="sw" style="background:#222;width:2px"></span>transition';
    if (prefix) $("timeline-legend").append(` · clip names without “${prefix}”`);
  }

  function drawConstraints() {
    const box = $("constraints-box");
    const cs = clip.constraints;
    if (!cs.length) { box.style.display = "none"; return; }
    box.style.display = "";
    const c = chartCanvas("constraints", cs.length * 22 + 8);
    const ctx = c.getContext("2d");
    ctx.font = "11px sans-serif";
    cs.forEach((k, r) => {
      const y = 4 + r * 22;
      const what = k.require.label !== undefined ? `label ${k.require.label}` : `contact ${k.require.contact}`;
      ctx.fillStyle = "#555";
      ctx.fillText(`set ${k.set}: ${what}`, 6, y + 14);
      for (let t = 0; t < k.met.length; t++) {
        ctx.fillStyle = k.met[t] === "1" ? "#2a9d3a" : "#d62828";
        const f = k.first_frame + t;
        ctx.fillRect(xOf(c, f), y, Math.max(1, xOf(c, f + 1) - xOf(c, f)), 18);
      }
    });
    finishChart("constraints", c);
  }

  function drawCharts() {
    for (const k of Object.keys(charts)) delete charts[k];
    drawErrors();
    drawSensors();
    drawTimeline();
    drawConstraints();
  }

  function drawCursors(i) {
    for (const { canvas, snap } of Object.values(charts)) {
      const ctx = canvas.getContext("2d");
      ctx.clearRect(0, 0, canvas.width, canvas.height);
      ctx.drawImage(snap, 0, 0);
      ctx.fillStyle = "rgba(214,40,40,0.9)";
      ctx.fillRect(xOf(canvas, i) - 0.5, 0, 1.5, canvas.height);
    }
  }

  for (const id of ["errors", "sensors", "timeline", "constraints"]) {
    $(id).addEventListener("click", (e) => {
      if (!clip) return;
      const r = e.target.getBoundingClientRect();
      setFrame(frameAt(e.target, e.clientX - r.left));
    });
  }
  $("timeline").addEventListener("mousemove", (e) => {
    if (!clip) return;
    const r = e.target.getBoundingClientRect();
    const info = frameInfo(frameAt(e.target, e.clientX - r.left));
    $("timeline-info").textContent = info;
    e.target.title = info; // (the full clip name as a tooltip too)
  });

  function frameInfo(i) {
    const s = clip.timeline.segments.find((g) => i >= g.start && i < g.start + g.frames);
    if (!s) return "";
    const src = s.clip ? `${s.clip} from frame ${s.from_frame + (i - s.start)}` : "";
    const err = clip.errors && clip.errors.joint_err_cm ? `; joint error ${clip.errors.joint_err_cm[i].toFixed(1)} cm` : "";
    return `frame ${i}: ${s.label}, ${s.kind}${src ? ", " + src : ""}${err}`;
  }

  // ------------------------------------------------------------ clips, playback, table

  function loadClip(k) {
    const c = DATA.clips[k];
    const T = c.frames;
    clearScene();
    clip = {
      index: k, T, rate: c.rate_hz, name: c.name, timeline: c.timeline, constraints: c.constraints,
      errors: c.errors, sensors: prepareSensors(c.sensors, T), markers: prepareMarkers(c.markers, T),
      figures: c.figures.map((f) => prepareFigure(f, T)),
    };
    clip.drawn = clip.figures.map((f) => buildFigure(f, T));
    clip.markerPoints = buildMarkers(clip.markers);
    $("layout-box").style.display = clip.figures.length > 1 ? "" : "none";
    $("legend").textContent = ["Blue: reconstruction", clip.figures.length > 1 ? "green: truth" : null,
      "red discs: feet in contact", clip.markers ? "orange: measured markers" : null].filter(Boolean).join("; ") + ".";
    $("clip-name").textContent = c.name;
    $("clip-info").textContent = Object.entries(c.info).map(([a, b]) => `${a}: ${b}`).join(" · ");
    $("scrub").max = String(T - 1);
    const f0 = clip.figures[0];
    orbit.target.set(centreX(f0, 0), 0.9, centreZ(f0, 0));
    placeGrid();
    layoutOffsets();
    frame = 0;
    playTime = 0;
    drawCharts();
    drawFrame(0);
    document.querySelectorAll("#clips tbody tr").forEach((tr) => tr.classList.toggle("sel", Number(tr.dataset.clip) === k));
  }

  function setFrame(i) {
    if (!clip) return;
    frame = Math.max(0, Math.min(clip.T - 1, Math.round(i)));
    playTime = frame / clip.rate;
    drawFrame(frame);
  }

  function setPlaying(on) {
    playing = on;
    lastTick = null;
    $("play").textContent = on ? "❚❚ pause" : "▶ play";
  }

  function tick(now) {
    if (playing && clip) {
      if (lastTick !== null) {
        playTime += (now - lastTick) / 1000 * Number($("speed").value);
        const f = Math.floor(playTime * clip.rate);
        if (f >= clip.T) { playTime = 0; }
        frame = Math.min(clip.T - 1, Math.floor(playTime * clip.rate));
        if (frame !== drawn) drawFrame(frame);
      }
      lastTick = now;
    }
    requestAnimationFrame(tick);
  }

  $("play").addEventListener("click", () => setPlaying(!playing));
  $("back").addEventListener("click", () => { setPlaying(false); setFrame(frame - 1); });
  $("fwd").addEventListener("click", () => { setPlaying(false); setFrame(frame + 1); });
  $("scrub").addEventListener("input", (e) => setFrame(Number(e.target.value)));
  $("layout").addEventListener("change", () => { layoutOffsets(); drawFrame(frame); });
  $("follow").addEventListener("change", () => drawFrame(frame));
  $("sensor").addEventListener("change", () => { drawSensors(); drawCursors(frame); });
  window.addEventListener("keydown", (e) => {
    if (e.target.tagName === "INPUT" && e.target.type !== "range") return;
    if (e.key === " ") { e.preventDefault(); setPlaying(!playing); }
    if (e.key === "ArrowRight") setFrame(frame + 1);
    if (e.key === "ArrowLeft") setFrame(frame - 1);
  });
  window.addEventListener("resize", resize);

  function buildTable() {
    const tbl = DATA.table;
    if (!tbl) { $("clips-box").style.display = "none"; return; }
    const head = $("clips").querySelector("thead tr");
    const body = $("clips").querySelector("tbody");
    let sortCol = -1, asc = true;
    const fmt = (v) => (v === null || v === undefined ? "—" : typeof v === "number" ? (Number.isInteger(v) ? String(v) : v.toFixed(2)) : String(v));
    function fill() {
      const rows = tbl.rows.map((r, i) => [r, i]);
      if (sortCol >= 0) {
        rows.sort((a, b) => {
          const x = a[0][sortCol], y = b[0][sortCol];
          if (x === y) return a[1] - b[1];
          if (x === null) return 1;
          if (y === null) return -1;
          return (x < y ? -1 : 1) * (asc ? 1 : -1);
        });
      }
      body.innerHTML = "";
      for (const [r, i] of rows) {
        const tr = document.createElement("tr");
        tr.dataset.clip = String(tbl.clip[i]);
        for (const v of r) { const td = document.createElement("td"); td.textContent = fmt(v); tr.appendChild(td); }
        tr.addEventListener("click", () => loadClip(tbl.clip[i]));
        if (clip && tbl.clip[i] === clip.index) tr.classList.add("sel");
        body.appendChild(tr);
      }
    }
    tbl.columns.forEach((name, k) => {
      const th = document.createElement("th");
      th.textContent = name;
      th.addEventListener("click", () => { asc = sortCol === k ? !asc : true; sortCol = k; fill(); });
      head.appendChild(th);
    });
    fill();
  }

  // ------------------------------------------------------------ test hook

  window.graphsvcViewer = {
    clips: () => DATA.clips.length,
    clip: () => (clip ? clip.index : -1),
    loadClip,
    frames: () => (clip ? clip.T : 0),
    frame: () => drawn,
    setFrame,
    play: () => setPlaying(true),
    pause: () => setPlaying(false),
    playing: () => playing,
    figures: () => clip.figures.map((f) => f.name),
    // the pose of frame i as the page holds it, metres, [J][3]
    jointPositions: (i, fig = 0) => {
      const f = clip.figures[fig];
      const out = [];
      for (let j = 0; j < f.J; j++) out.push([0, 1, 2].map((c) => f.pos[(i * f.J + j) * 3 + c]));
      return out;
    },
    // the joints as drawn now (the points' buffer, without the side-by-side offset),
    // [J][3] metres, null for a joint not drawn
    drawnJointPositions: (fig = 0) => {
      const d = clip.drawn[fig];
      const a = d.points.geometry.attributes.position.array;
      const out = new Array(d.fig.J).fill(null);
      d.fig.drawn.forEach((j, k) => { out[j] = [a[k * 3] - d.offset, a[k * 3 + 1], a[k * 3 + 2]]; });
      return out;
    },
    // the bones drawn, [parent, child] joint pairs
    drawnBones: (fig = 0) => {
      const b = clip.drawn[fig].bones;
      const out = [];
      for (let k = 0; k < b.length; k += 2) out.push([b[k], b[k + 1]]);
      return out;
    },
    // the joint the page follows (gather.py centre_joint)
    centre: (fig = 0) => clip.figures[fig].centre,
    // the drawn joints projected by the page's camera as drawn now: [J][3] normalized
    // device coordinates (x, y in −1..1 on the canvas, z in −1..1 between the near and
    // far planes), null for a joint not drawn
    projectedJoints: (fig = 0) => {
      const d = clip.drawn[fig];
      const a = d.points.geometry.attributes.position.array;
      const out = new Array(d.fig.J).fill(null);
      d.fig.drawn.forEach((j, k) => {
        const v = new THREE.Vector3(a[k * 3], a[k * 3 + 1], a[k * 3 + 2]).project(camera);
        out[j] = [v.x, v.y, v.z];
      });
      return out;
    },
  };

  buildTable();
  resize();
  loadClip(0);
  resize(); // (again: the page's scroll bar came with the charts)
  requestAnimationFrame(tick);
  window.graphsvcViewer.ready = true;
})();
