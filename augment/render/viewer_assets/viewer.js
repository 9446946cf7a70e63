// motionaug viewer: a clip list and side-by-side 3D stick figures in hand-written WebGL, offline.
// Data arrive as classic scripts (a file:// page can neither fetch() nor import): index.js calls
// motionaugIndex(), each chunk calls motionaugChunk(n, records). Without WebGL: key-pose strips on a 2D canvas.
(function () {
  "use strict";
  var COLORS = [[0.12, 0.47, 0.71], [0.84, 0.15, 0.16], [0.17, 0.63, 0.17], [0.58, 0.40, 0.74], [1.0, 0.50, 0.05]];
  var HEX = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e"];
  var ROW_H = 22, KEEP_CHUNKS = 48;

  var V = (window.motionViewer = {
    mode: null, ready: false, index: null, panels: [], t: 0, duration: 0, playing: true, speed: 1,
    azimuth: 0.6, elevation: 0.35, zoom: 1, orbit: false, selected: -1, firstFrameMs: null, errors: []
  });
  var chunks = {}, chunkOrder = [], waiting = {}, decoded = {};
  var gl = null, prog = null, buf = null, lastGeometry = null;
  var order = [], bySource = {}, haystack = null, checkedStyles = {};
  var el = function (id) { return document.getElementById(id); };

  window.motionaugChunk = function (n, records) {
    chunks[n] = records;
    chunkOrder.push(n);
    while (chunkOrder.length > KEEP_CHUNKS) {  // bounded memory on a long browsing session
      var old = chunkOrder.shift();
      Object.keys(chunks[old] || {}).forEach(function (k) { delete decoded[k]; });
      delete chunks[old];
    }
    var callbacks = waiting[n] || [];
    delete waiting[n];
    callbacks.forEach(function (f) { f(); });
  };

  function loadChunk(n, done) {
    if (chunks[n]) return done();
    if (waiting[n]) return waiting[n].push(done);
    waiting[n] = [done];
    var s = document.createElement("script");
    s.src = "viewer/chunks/c" + String(n).padStart(5, "0") + ".js";
    s.onerror = function () { notice("could not load " + s.src); };
    document.head.appendChild(s);
  }

  function notice(text) { V.errors.push(text); el("notice").textContent = text; }

  function bytes(b64) {
    var s = atob(b64), out = new Uint8Array(s.length);
    for (var i = 0; i < s.length; i++) out[i] = s.charCodeAt(i);
    return out.buffer;
  }

  // one record -> {n, fps, pos: Float32Array(n*J*3) metres, contacts, captions}
  function decode(key, rec) {
    if (decoded[key]) return decoded[key];
    var J = V.index.skeleton.parents.length, n = rec.n;
    var root = new Float32Array(bytes(rec.root)), rel = new Int16Array(bytes(rec.rel));
    var pos = new Float32Array(n * J * 3);
    for (var f = 0; f < n; f++)
      for (var j = 0; j < J; j++)
        for (var k = 0; k < 3; k++) pos[(f * J + j) * 3 + k] = root[f * 3 + k] + rel[(f * J + j) * 3 + k] / 1000;
    return (decoded[key] = { key: key, n: n, fps: rec.fps, pos: pos, contacts: rec.contacts,
      captions: rec.captions || [], before: rec.before || null });
  }

  // ---- the clip list ---------------------------------------------------------------------------------

  window.motionaugIndex = function (index) {
    V.index = index;
    var c = index.clips, sortSel = el("sort");
    c.id.forEach(function (id, i) { (bySource[c.source[i]] = bySource[c.source[i]] || []).push(i); });
    var opt = function (value, label) {
      var o = document.createElement("option"); o.value = value; o.textContent = label; sortSel.appendChild(o);
    };
    index.scores.forEach(function (s) { opt(s.name, s.label + (s.higher_better ? " (worst first)" : " (highest first)")); });
    opt("id", "id");
    opt("frames", "frames");
    sortSel.value = index.default_sort || "id";
    V.ascending = true;
    sortSel.onchange = function () { V.ascending = true; refresh(); };
    el("order").onclick = function () { V.ascending = !V.ascending; refresh(); };
    var timer = null;
    el("search").oninput = function () { clearTimeout(timer); timer = setTimeout(refresh, 120); };
    el("list").onscroll = drawRows;
    window.addEventListener("resize", function () {
      drawRows();
      if (V.mode === "strips" && V.panels.length) drawStrips(); else draw();
    });
    setup3d();
    refresh();
    if (order.length) V.select(c.id[order[0]]);
  };

  function scoreOf(name, i) {
    var c = V.index.clips;
    if (name === "id") return c.id[i];
    if (name === "frames") return c.frames[i];
    return c.scores[name][i];
  }

  function refresh() {
    var c = V.index.clips, name = el("sort").value, q = el("search").value.trim().toLowerCase();
    if (q && !haystack)
      haystack = c.id.map(function (id, i) {
        return [id, c.style[i], c.content[i], c.caption[i], c.before[i]].join(" ").toLowerCase();
      });
    order = [];
    for (var i = 0; i < c.id.length; i++) if (!q || haystack[i].indexOf(q) >= 0) order.push(i);
    var spec = V.index.scores.filter(function (s) { return s.name === name; })[0];
    var sign = (spec && !spec.higher_better ? -1 : 1) * (V.ascending ? 1 : -1);
    order.sort(function (a, b) {
      var x = scoreOf(name, a), y = scoreOf(name, b);
      if (x === null || x === undefined) return y === null || y === undefined ? a - b : 1;  // empty scores last
      if (y === null || y === undefined) return -1;
      return (x < y ? -1 : x > y ? 1 : a - b) * sign;
    });
    el("order").textContent = V.ascending ? "worst first" : "best first";
    el("count").textContent = order.length + " of " + c.id.length + " clips";
    el("spacer").style.height = order.length * ROW_H + "px";
    drawRows();
  }

  function fmt(v, name) {  // scores with 3 decimals, counts as they are
    if (v === null || v === undefined) return "–";
    if (typeof v !== "number" || name === "frames") return String(v);
    return Math.abs(v) < 1000 ? v.toFixed(3) : v.toPrecision(4);
  }

  function drawRows() {
    var list = el("list"), c = V.index.clips, name = el("sort").value;
    var first = Math.floor(list.scrollTop / ROW_H), last = Math.min(order.length, first + Math.ceil(list.clientHeight / ROW_H) + 2);
    Array.prototype.slice.call(list.querySelectorAll(".row")).forEach(function (r) { r.remove(); });
    for (var r = first; r < last; r++) {
      var i = order[r], div = document.createElement("div");
      div.className = "row" + (i === V.selected ? " sel" : "");
      div.style.top = r * ROW_H + "px";
      div.dataset.id = c.id[i];
      div.title = c.caption[i];
      var score = document.createElement("span");
      score.className = "score";
      score.textContent = name === "id" ? "" : fmt(scoreOf(name, i), name);
      div.appendChild(score);
      div.appendChild(document.createTextNode(c.id[i] + (c.style[i] ? " · " + c.style[i] : "")));
      div.onclick = (function (id) { return function () { V.select(id); }; })(c.id[i]);
      list.appendChild(div);
    }
  }

  // ---- choosing what to show -------------------------------------------------------------------------

  V.select = function (id, done) {
    var c = V.index.clips, i = c.id.indexOf(id);
    if (i < 0) { notice("no clip " + id); return; }
    V.selected = i;
    drawRows();
    var source = c.source[i], siblings = bySource[source] || [i];
    if (!checkedStyles[c.style[i]]) { checkedStyles = {}; checkedStyles[c.style[i]] = true; }
    var box = el("styles");
    box.textContent = "";
    if (V.index.kind === "run") {
      box.appendChild(document.createTextNode("styles of " + source + ": "));
      siblings.forEach(function (j) {
        var label = document.createElement("label"), cb = document.createElement("input");
        cb.type = "checkbox"; cb.checked = !!checkedStyles[c.style[j]]; cb.value = c.style[j];
        cb.onchange = function () { checkedStyles[cb.value] = cb.checked; show(i, null); };
        label.appendChild(cb); label.appendChild(document.createTextNode(" " + c.style[j]));
        box.appendChild(label);
      });
    }
    show(i, done);
  };

  function show(i, done) {
    var c = V.index.clips, source = c.source[i], wanted = [];
    var srcChunk = V.index.source_chunks ? V.index.source_chunks[source] : c.chunk[i];
    wanted.push({ key: "src:" + source, chunk: srcChunk, title: V.index.kind === "run" ? "content " + source : source });
    if (V.index.kind === "run")
      (bySource[source] || []).forEach(function (j) {
        if (checkedStyles[c.style[j]]) wanted.push({ key: c.id[j], chunk: c.chunk[j], title: c.style[j] });
      });
    var left = wanted.length;
    wanted.forEach(function (w) {
      loadChunk(w.chunk, function () {
        if (--left > 0) return;
        if (V.selected !== i) return;  // another clip was picked meanwhile
        V.panels = wanted.map(function (w, p) {
          var d = decode(w.key, chunks[w.chunk][w.key]);
          return { key: w.key, title: w.title, m: d, color: p % COLORS.length };
        });
        V.duration = Math.max.apply(null, V.panels.map(function (p) { return p.m.n / p.m.fps; }));
        V.t = 0;
        prepareScene();
        showCaptions();
        el("labels").innerHTML = "";
        V.panels.forEach(function (p) {
          var d = document.createElement("div"); d.textContent = p.title; d.style.color = HEX[p.color];
          el("labels").appendChild(d);
        });
        draw();
        V.ready = true;
        if (done) done();
      });
    });
  }

  function showCaptions() {
    var box = el("captions");
    box.textContent = "";
    var line = function (head, texts) {
      var p = document.createElement("div"), b = document.createElement("b");
      b.textContent = head; p.appendChild(b); p.appendChild(document.createTextNode(" " + texts.join(" | ")));
      box.appendChild(p);
    };
    V.panels.forEach(function (p, k) {
      if (k === 0) line(V.index.kind === "run" ? "before" : "captions", p.m.captions);
      else line("after (" + p.title + ")", p.m.captions);
    });
  }

  // ---- the clock -------------------------------------------------------------------------------------

  function frameOf(p, t) { return Math.max(0, Math.min(p.m.n - 1, Math.floor(t * p.m.fps + 1e-6))); }

  V.seek = function (seconds) { V.t = Math.max(0, Math.min(V.duration, seconds)); draw(); };
  V.setFrame = function (f) { V.seek(f / V.panels[0].m.fps); };  // frame f of the content clip
  V.play = function (on) { V.playing = on; el("play").textContent = on ? "pause" : "play"; };

  // ---- 3D --------------------------------------------------------------------------------------------

  var VS = "attribute vec3 p; attribute vec3 c; uniform mat4 m; uniform float s; varying vec3 v;" +
    "void main(){ gl_Position = m * vec4(p, 1.0); gl_PointSize = s; v = c; }";
  var FS = "precision mediump float; varying vec3 v; void main(){ gl_FragColor = vec4(v, 1.0); }";

  function setup3d() {
    var canvas = el("gl");
    try {
      gl = canvas.getContext("webgl", { antialias: true, preserveDrawingBuffer: true });
    } catch (e) { gl = null; }
    if (!gl) {
      V.mode = "strips";
      canvas.hidden = true;
      el("strips").hidden = false;
      el("labels").hidden = true;
      el("controls").style.display = "none";
      notice("This browser has no WebGL: showing key-pose strips (front view) instead of the 3D player.");
      return;
    }
    V.mode = "webgl";
    var sh = function (type, src) {
      var s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s); return s;
    };
    prog = gl.createProgram();
    gl.attachShader(prog, sh(gl.VERTEX_SHADER, VS));
    gl.attachShader(prog, sh(gl.FRAGMENT_SHADER, FS));
    gl.linkProgram(prog);
    buf = gl.createBuffer();
    var drag = null;
    canvas.onmousedown = function (e) { drag = [e.clientX, e.clientY]; };
    window.addEventListener("mouseup", function () { drag = null; });
    window.addEventListener("mousemove", function (e) {
      if (!drag) return;
      V.azimuth -= (e.clientX - drag[0]) * 0.01;
      V.elevation = Math.max(-0.2, Math.min(1.4, V.elevation + (e.clientY - drag[1]) * 0.01));
      drag = [e.clientX, e.clientY];
      draw();
    });
    canvas.addEventListener("wheel", function (e) {
      e.preventDefault(); V.zoom = Math.max(0.3, Math.min(4, V.zoom * Math.exp(e.deltaY * 0.001))); draw();
    }, { passive: false });
    el("play").onclick = function () { V.play(!V.playing); };
    el("scrub").oninput = function () { V.play(false); V.seek(+el("scrub").value * V.duration); };
    el("speed").onchange = function () { V.speed = +el("speed").value; };
    el("orbit").onchange = function () { V.orbit = el("orbit").checked; };
    var last = null;
    var tick = function (now) {
      var dt = last === null ? 0 : Math.min(0.1, (now - last) / 1000);
      last = now;
      if (V.panels.length && (V.playing || V.orbit)) {
        if (V.playing) { V.t += dt * V.speed; if (V.t >= V.duration) V.t = V.duration > 0 ? V.t % V.duration : 0; }
        if (V.orbit) V.azimuth += dt * 0.4;
        draw();
      }
      requestAnimationFrame(tick);
    };
    requestAnimationFrame(tick);
  }

  // per panel: the ground grid around its root path
  function prepareScene() {
    var J = V.index.skeleton.parents.length;
    V.panels.forEach(function (p) {
      var pos = p.m.pos, x0 = 1e9, x1 = -1e9, z0 = 1e9, z1 = -1e9;
      for (var f = 0; f < p.m.n; f++) {
        var x = pos[f * J * 3], z = pos[f * J * 3 + 2];
        x0 = Math.min(x0, x); x1 = Math.max(x1, x); z0 = Math.min(z0, z); z1 = Math.max(z1, z);
      }
      p.box = [Math.floor(x0) - 1, Math.ceil(x1) + 1, Math.floor(z0) - 1, Math.ceil(z1) + 1];
    });
    if (V.mode === "strips") drawStrips();
  }

  function matmul(a, b) {  // column-major 4x4
    var o = new Float32Array(16);
    for (var i = 0; i < 4; i++) for (var j = 0; j < 4; j++) {
      var s = 0; for (var k = 0; k < 4; k++) s += a[k * 4 + j] * b[i * 4 + k]; o[i * 4 + j] = s;
    }
    return o;
  }
  function perspective(fovy, aspect, near, far) {
    var f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
    return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0]);
  }
  function lookAt(eye, at) {
    var z = norm([eye[0] - at[0], eye[1] - at[1], eye[2] - at[2]]), x = norm(cross([0, 1, 0], z)), y = cross(z, x);
    return new Float32Array([x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
      -dot(x, eye), -dot(y, eye), -dot(z, eye), 1]);
  }
  function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
  function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
  function norm(a) { var l = Math.sqrt(dot(a, a)) || 1; return [a[0] / l, a[1] / l, a[2] / l]; }

  // the vertices of one panel at time t: [lines (x,y,z,r,g,b)...], [points ...], and where the bones start
  function geometry(p, t) {
    var J = V.index.skeleton.parents.length, parents = V.index.skeleton.parents, feet = V.index.skeleton.feet;
    var f = frameOf(p, t), pos = p.m.pos, col = COLORS[p.color], lines = [], points = [];
    var b = p.box, g = [0.82, 0.82, 0.85];
    for (var x = b[0]; x <= b[1]; x++) lines.push(x, 0, b[2], g[0], g[1], g[2], x, 0, b[3], g[0], g[1], g[2]);
    for (var z = b[2]; z <= b[3]; z++) lines.push(b[0], 0, z, g[0], g[1], g[2], b[1], 0, z, g[0], g[1], g[2]);
    for (var k = 1; k < p.m.n; k++) {
      var a0 = (k - 1) * J * 3, a1 = k * J * 3, shade = k <= f ? 0.35 : 0.7;
      lines.push(pos[a0], 0.003, pos[a0 + 2], shade, shade, shade, pos[a1], 0.003, pos[a1 + 2], shade, shade, shade);
    }
    var boneStart = lines.length / 6;
    for (var j = 1; j < J; j++) {
      var pj = parents[j], o = f * J * 3;
      lines.push(pos[o + pj * 3], pos[o + pj * 3 + 1], pos[o + pj * 3 + 2], col[0], col[1], col[2],
        pos[o + j * 3], pos[o + j * 3 + 1], pos[o + j * 3 + 2], col[0], col[1], col[2]);
    }
    var bits = parseInt(p.m.contacts.charAt(f) || "0", 16);
    feet.forEach(function (jf, q) {
      if (bits & (1 << q)) points.push(pos[f * J * 3 + jf * 3], pos[f * J * 3 + jf * 3 + 1], pos[f * J * 3 + jf * 3 + 2], 0.1, 0.75, 0.2);
    });
    return { frame: f, lines: new Float32Array(lines), points: new Float32Array(points), boneStart: boneStart };
  }

  function draw() {
    if (!V.panels.length) return;
    var f0 = frameOf(V.panels[0], V.t);
    el("scrub").value = V.duration ? V.t / V.duration : 0;
    el("time").textContent = V.t.toFixed(2) + " s / " + V.duration.toFixed(2) + " s · frame " + (f0 + 1) + "/" + V.panels[0].m.n;
    if (V.mode !== "webgl") return;
    var canvas = el("gl"), w = canvas.clientWidth, h = canvas.clientHeight, dpr = window.devicePixelRatio || 1;
    if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
      canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr);
    }
    gl.useProgram(prog);
    gl.enable(gl.DEPTH_TEST);
    gl.enable(gl.SCISSOR_TEST);
    gl.bindBuffer(gl.ARRAY_BUFFER, buf);
    var locP = gl.getAttribLocation(prog, "p"), locC = gl.getAttribLocation(prog, "c");
    gl.enableVertexAttribArray(locP); gl.enableVertexAttribArray(locC);
    var n = V.panels.length, pw = Math.floor(canvas.width / n), drawn = [];
    V.panels.forEach(function (p, i) {
      gl.viewport(i * pw, 0, pw, canvas.height);
      gl.scissor(i * pw, 0, pw, canvas.height);
      gl.clearColor(1, 1, 1, 1);
      gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      var d = 4 * V.zoom, f = frameOf(p, V.t) * V.index.skeleton.parents.length * 3;
      var a = [p.m.pos[f], 0.9, p.m.pos[f + 2]];  // the camera follows the root
      var eye = [a[0] + d * Math.cos(V.elevation) * Math.sin(V.azimuth), a[1] + d * Math.sin(V.elevation),
        a[2] + d * Math.cos(V.elevation) * Math.cos(V.azimuth)];
      var mvp = matmul(perspective(0.8, pw / canvas.height, 0.05, 200), lookAt(eye, a));
      gl.uniformMatrix4fv(gl.getUniformLocation(prog, "m"), false, mvp);
      gl.uniform1f(gl.getUniformLocation(prog, "s"), 7 * dpr);
      var geo = geometry(p, V.t);
      [[geo.lines, gl.LINES], [geo.points, gl.POINTS]].forEach(function (pair) {
        if (!pair[0].length) return;
        gl.bufferData(gl.ARRAY_BUFFER, pair[0], gl.DYNAMIC_DRAW);
        gl.vertexAttribPointer(locP, 3, gl.FLOAT, false, 24, 0);
        gl.vertexAttribPointer(locC, 3, gl.FLOAT, false, 24, 12);
        gl.drawArrays(pair[1], 0, pair[0].length / 6);
      });
      drawn.push({ key: p.key, geo: geo });
    });
    lastGeometry = drawn;
    if (V.firstFrameMs === null) V.firstFrameMs = performance.now();
  }

  // what the last draw uploaded, read back from its vertex arrays: per panel the frame and the joints (J, 3)
  V.drawn = function () {
    var parents = V.index.skeleton.parents, J = parents.length;
    return (lastGeometry || []).map(function (d) {
      var joints = [], L = d.geo.lines;
      for (var j = 1; j < J; j++) {
        var v = (d.geo.boneStart + 2 * (j - 1)) * 6;  // the bone (parent j -> j): two vertices
        joints[parents[j]] = joints[parents[j]] || [L[v], L[v + 1], L[v + 2]];
        joints[j] = [L[v + 6], L[v + 7], L[v + 8]];
      }
      return { key: d.key, frame: d.geo.frame, joints: joints, contacts: d.geo.points.length / 6 };
    });
  };

  // ---- without WebGL: key-pose strips, front view --------------------------------------------------

  function drawStrips() {
    var canvas = el("strips"), w = canvas.clientWidth, h = canvas.clientHeight;
    canvas.width = w; canvas.height = h;
    var ctx = canvas.getContext("2d"), J = V.index.skeleton.parents.length, parents = V.index.skeleton.parents;
    var rows = V.panels.length, rh = h / rows, poses = 6, cw = w / poses;
    ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, w, h);
    V.panels.forEach(function (p, r) {
      var scale = Math.min(cw, rh - 18) / 2.2;
      ctx.strokeStyle = HEX[p.color]; ctx.lineWidth = 2;
      for (var k = 0; k < poses; k++) {
        var f = Math.round(k * (p.m.n - 1) / Math.max(1, poses - 1)), o = f * J * 3, cx = (k + 0.5) * cw, base = (r + 1) * rh - 6;
        var px = function (j) { return cx + (p.m.pos[o + j * 3] - p.m.pos[o]) * scale; };
        var py = function (j) { return base - p.m.pos[o + j * 3 + 1] * scale; };
        ctx.beginPath();
        for (var j = 1; j < J; j++) { ctx.moveTo(px(parents[j]), py(parents[j])); ctx.lineTo(px(j), py(j)); }
        ctx.stroke();
      }
      ctx.fillStyle = "#333"; ctx.fillText(p.title, 6, r * rh + 14);
    });
    if (V.firstFrameMs === null) V.firstFrameMs = performance.now();
  }
})();
