// pointcvx viewer: a decomposition drawn with WebGL 1, no library, no network.
// The page embeds the scene as JSON (<script id="pointcvx-drawing">, arrays as little-endian
// base64); this script decodes it, draws the points (opaque, shaded by their normals), the
// points isolation removed (grey), the hulls (translucent, one colour each, back faces then
// front faces per hull, hulls far to near) and the hulls' creases, and lets the mouse orbit
// around the up axis, pan and zoom.
(function () {
  "use strict";

  var scene = JSON.parse(document.getElementById("pointcvx-drawing").textContent);
  var canvas = document.getElementById("view");

  // ------------------------------------------------------------------ data
  function decode(text, Type) {
    if (!text) return null;
    var bin = atob(text), bytes = new Uint8Array(bin.length);
    for (var i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return new Type(bytes.buffer);
  }

  var P = scene.points;
  var pointPos = decode(P.positions, Float32Array);
  var pointCol = P.colors ? decode(P.colors, Uint8Array) : null;
  var pointNrm = P.normals ? decode(P.normals, Int8Array) : null;
  var pointLab = P.labels ? decode(P.labels, Int32Array) : null;
  var removedPos = scene.removed ? decode(scene.removed.positions, Float32Array) : null;
  var hulls = scene.hulls.map(function (h, k) {
    var v = decode(h.vertices, Float32Array), f = decode(h.faces, Uint32Array);
    var e = decode(h.edges, Uint32Array);
    // one vertex per triangle corner, with the face normal: flat shading
    var pos = new Float32Array(f.length * 3), nrm = new Float32Array(f.length * 3);
    var cx = 0, cy = 0, cz = 0, nv = v.length / 3;
    for (var i = 0; i < nv; i++) { cx += v[3 * i]; cy += v[3 * i + 1]; cz += v[3 * i + 2]; }
    for (var t = 0; t < f.length; t += 3) {
      var a = 3 * f[t], b = 3 * f[t + 1], c = 3 * f[t + 2];
      var ux = v[b] - v[a], uy = v[b + 1] - v[a + 1], uz = v[b + 2] - v[a + 2];
      var wx = v[c] - v[a], wy = v[c + 1] - v[a + 1], wz = v[c + 2] - v[a + 2];
      var nx = uy * wz - uz * wy, ny = uz * wx - ux * wz, nz = ux * wy - uy * wx;
      var len = Math.sqrt(nx * nx + ny * ny + nz * nz) || 1;
      for (var j = 0; j < 3; j++) {
        var s = 3 * f[t + j];
        pos.set([v[s], v[s + 1], v[s + 2]], 3 * (t + j));
        nrm.set([nx / len, ny / len, nz / len], 3 * (t + j));
      }
    }
    var lines = new Float32Array(e.length * 3);
    for (var m = 0; m < e.length; m++) lines.set([v[3 * e[m]], v[3 * e[m] + 1], v[3 * e[m] + 2]], 3 * m);
    return { color: h.color, pos: pos, nrm: nrm, lines: lines, visible: true,
             center: [cx / nv, cy / nv, cz / nv], vertices: nv, faces: f.length / 3, index: k };
  });

  // ------------------------------------------------------------------ small matrix kit
  function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
  function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
  function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
  function norm(a) { var l = Math.sqrt(dot(a, a)) || 1; return [a[0] / l, a[1] / l, a[2] / l]; }
  function lookAt(eye, target, up) {  // column-major view matrix
    var z = norm(sub(eye, target)), x = norm(cross(up, z)), y = cross(z, x);
    return [x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
            -dot(x, eye), -dot(y, eye), -dot(z, eye), 1];
  }
  function perspective(fovy, aspect, near, far) {
    var f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
    return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0];
  }
  function mul(a, b) {  // a * b, column-major
    var o = new Array(16);
    for (var c = 0; c < 4; c++) for (var r = 0; r < 4; r++) {
      var s = 0;
      for (var k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
      o[c * 4 + r] = s;
    }
    return o;
  }

  // ------------------------------------------------------------------ camera
  var AXES = { x: [1, 2], y: [2, 0], z: [0, 1] };  // horizontal axes h1, h2 with h1 x h2 = up
  var upName = scene.up || "z", axis = upName.charAt(upName.length - 1), sign = upName.charAt(0) === "-" ? -1 : 1;
  var UP = [0, 0, 0], H1 = [0, 0, 0], H2 = [0, 0, 0];
  UP["xyz".indexOf(axis)] = sign;
  H1[AXES[axis][sign > 0 ? 0 : 1]] = 1;
  H2[AXES[axis][sign > 0 ? 1 : 0]] = 1;
  var FOV = 30 * Math.PI / 180, RADIUS = scene.radius || 1;
  var cam = {};
  var HALF = scene.half_extent || [RADIUS, RADIUS, RADIUS];
  function resetCamera() {
    cam.azimuth = -60 * Math.PI / 180;
    cam.elevation = 22 * Math.PI / 180;
    cam.target = [0, 0, 0];
    // back off until the 8 corners of the box fit the window with a margin
    cam.distance = 1;
    var e = eye(), z = norm(e), x = norm(cross(UP, z)), y = cross(z, x);
    var aspect = canvas.clientWidth / Math.max(canvas.clientHeight, 1) || 1.5, t = Math.tan(FOV / 2), need = 0;
    for (var k = 0; k < 8; k++) {
      var c = [k & 1 ? HALF[0] : -HALF[0], k & 2 ? HALF[1] : -HALF[1], k & 4 ? HALF[2] : -HALF[2]];
      var depth = dot(c, z);  // towards the viewer
      need = Math.max(need, depth + Math.abs(dot(c, y)) / (0.88 * t),
                      depth + Math.abs(dot(c, x)) / (0.88 * t * aspect));
    }
    cam.distance = need || RADIUS / Math.sin(FOV / 2);
  }
  resetCamera();
  function eye() {
    var ce = Math.cos(cam.elevation), se = Math.sin(cam.elevation);
    var ca = Math.cos(cam.azimuth), sa = Math.sin(cam.azimuth);
    var d = [0, 1, 2].map(function (i) { return ce * (ca * H1[i] + sa * H2[i]) + se * UP[i]; });
    return [cam.target[0] + cam.distance * d[0], cam.target[1] + cam.distance * d[1],
            cam.target[2] + cam.distance * d[2]];
  }

  // ------------------------------------------------------------------ GL
  var gl = canvas.getContext("webgl", { antialias: true, premultipliedAlpha: false, preserveDrawingBuffer: true });
  if (!gl) {
    document.getElementById("nogl").style.display = "block";
    fillLegend();
    return;
  }
  function shader(type, src) {
    var s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    return s;
  }
  function program(vs, fs) {
    var p = gl.createProgram();
    gl.attachShader(p, shader(gl.VERTEX_SHADER, vs));
    gl.attachShader(p, shader(gl.FRAGMENT_SHADER, fs));
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
    p.a = {}; p.u = {};
    var i, n = gl.getProgramParameter(p, gl.ACTIVE_ATTRIBUTES);
    for (i = 0; i < n; i++) { var a = gl.getActiveAttrib(p, i).name; p.a[a] = gl.getAttribLocation(p, a); }
    n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (i = 0; i < n; i++) { var u = gl.getActiveUniform(p, i).name; p.u[u] = gl.getUniformLocation(p, u); }
    return p;
  }
  var pointProg = program(
    "attribute vec3 aPos; attribute vec3 aColor; attribute vec3 aNormal;" +
    "uniform mat4 uMVP; uniform float uSize; uniform float uShade; uniform vec3 uLight; varying vec3 vColor;" +
    "void main() { gl_Position = uMVP * vec4(aPos, 1.0); gl_PointSize = uSize;" +
    "  float l = abs(dot(aNormal, uLight)); vColor = aColor * mix(1.0, 0.5 + 0.5 * l, uShade); }",
    "precision mediump float; varying vec3 vColor;" +
    "void main() { vec2 d = gl_PointCoord - 0.5; if (dot(d, d) > 0.25) discard; gl_FragColor = vec4(vColor, 1.0); }");
  var hullProg = program(
    "attribute vec3 aPos; attribute vec3 aNormal; uniform mat4 uMVP; uniform vec3 uLight; varying float vShade;" +
    "void main() { gl_Position = uMVP * vec4(aPos, 1.0); vShade = 0.55 + 0.45 * abs(dot(aNormal, uLight)); }",
    "precision mediump float; uniform vec3 uColor; uniform float uAlpha; varying float vShade;" +
    "void main() { gl_FragColor = vec4(uColor * vShade, uAlpha); }");
  var lineProg = program(
    "attribute vec3 aPos; uniform mat4 uMVP; void main() { gl_Position = uMVP * vec4(aPos, 1.0); }",
    "precision mediump float; uniform vec3 uColor; uniform float uAlpha;" +
    "void main() { gl_FragColor = vec4(uColor, uAlpha); }");

  function buffer(data) {
    var b = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, b);
    gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    return b;
  }
  var n = P.count;
  var DEFAULT = scene.point_color, REMOVED = scene.removed_color;
  var ownColors = new Float32Array(3 * n), hullColors = new Float32Array(3 * n);
  for (var i = 0; i < n; i++) {
    for (var c = 0; c < 3; c++) {
      ownColors[3 * i + c] = pointCol ? pointCol[3 * i + c] / 255 : DEFAULT[c];
      var lab = pointLab ? pointLab[i] : -1;
      hullColors[3 * i + c] = lab >= 0 && lab < hulls.length ? hulls[lab].color[c] : REMOVED[c];
    }
  }
  var normals = new Float32Array(3 * n);
  if (pointNrm) for (i = 0; i < 3 * n; i++) normals[i] = pointNrm[i] / 127;
  var buf = {
    pos: buffer(pointPos), own: buffer(ownColors), byHull: buffer(hullColors), nrm: buffer(normals),
    removed: removedPos ? buffer(removedPos) : null,
  };
  hulls.forEach(function (h) { h.bPos = buffer(h.pos); h.bNrm = buffer(h.nrm); h.bLines = buffer(h.lines); });

  function attrib(prog, name, b) {
    var loc = prog.a[name];
    if (loc === undefined) return;
    gl.bindBuffer(gl.ARRAY_BUFFER, b);
    gl.enableVertexAttribArray(loc);
    gl.vertexAttribPointer(loc, 3, gl.FLOAT, false, 0, 0);
  }
  function constant(prog, name, v) {
    var loc = prog.a[name];
    if (loc === undefined) return;
    gl.disableVertexAttribArray(loc);
    gl.vertexAttrib3f(loc, v[0], v[1], v[2]);
  }

  // ------------------------------------------------------------------ state and controls
  var ui = {
    points: true, hulls: true, edges: true, removed: true, byHull: false,
    size: defaultPointSize(), alpha: 0.32,
  };
  function defaultPointSize() {
    var total = n + (removedPos ? removedPos.length / 3 : 0);
    return Math.max(1.5, Math.min(5, 2.2 * Math.sqrt(60000 / Math.max(total, 1))));
  }
  function control(id, key, kind) {
    var el = document.getElementById(id);
    if (!el) return;
    if (kind === "check") {
      el.checked = ui[key];
      el.addEventListener("change", function () { ui[key] = el.checked; draw(); });
    } else {
      el.value = ui[key];
      el.addEventListener("input", function () { ui[key] = parseFloat(el.value); draw(); });
    }
  }
  control("show-points", "points", "check");
  control("show-hulls", "hulls", "check");
  control("show-edges", "edges", "check");
  control("show-removed", "removed", "check");
  control("by-hull", "byHull", "check");
  control("point-size", "size", "range");
  control("hull-alpha", "alpha", "range");
  if (!removedPos) document.getElementById("row-removed").style.display = "none";
  if (!pointLab) document.getElementById("row-by-hull").style.display = "none";
  document.getElementById("reset").addEventListener("click", function () { resetCamera(); draw(); });

  function fillLegend() {
    var L = scene.legend, rows = [];
    document.getElementById("title").textContent = L.title || "pointcvx";
    rows.push([L.hulls + (L.hulls === 1 ? " hull" : " hulls"), ""]);
    if (L.max_concavity !== null && L.max_concavity !== undefined) rows.push(["max concavity", L.max_concavity.toFixed(4)]);
    if (L.seconds !== null && L.seconds !== undefined) rows.push(["time", L.seconds.toFixed(2) + " s"]);
    if (L.features) rows.push(["features", L.features]);
    if (L.modality) rows.push(["input", L.modality]);
    if (L.hulls_file) rows.push(["hulls from", L.hulls_file]);
    rows.push(["points", L.points === L.points_total ? L.points.toLocaleString()
               : L.points.toLocaleString() + " of " + L.points_total.toLocaleString()]);
    if (L.removed) rows.push(["removed", L.removed.toLocaleString() + " (grey)"]);
    if (L.noise) rows.push(["noise", L.noise.toLocaleString() + " points in no hull"]);
    if (L.resolved_threshold) rows.push(["sparse", "cut at " + L.resolved_threshold.toPrecision(3)]);
    if (L.static) rows.push(["static", L.static + " (held by what the capture does not show)"]);
    var table = document.getElementById("stats");
    rows.forEach(function (r) {
      var tr = document.createElement("tr"), a = document.createElement("td"), b = document.createElement("td");
      a.textContent = r[0]; b.textContent = r[1];
      tr.appendChild(a); tr.appendChild(b); table.appendChild(tr);
    });
    var box = document.getElementById("swatches");
    hulls.forEach(function (h) {
      var s = document.createElement("span");
      s.className = "swatch";
      s.style.background = "rgb(" + h.color.map(function (x) { return Math.round(255 * x); }).join(",") + ")";
      s.title = "hull " + h.index + ": " + h.vertices + " vertices, " + h.faces + " triangles (click: hide/show)";
      s.addEventListener("click", function () {
        h.visible = !h.visible;
        s.classList.toggle("off", !h.visible);
        if (gl) draw();
      });
      box.appendChild(s);
    });
  }
  fillLegend();

  // ------------------------------------------------------------------ drawing
  var pending = false;
  function draw() {
    if (!pending) { pending = true; requestAnimationFrame(render); }
  }
  function resize() {
    var dpr = window.devicePixelRatio || 1;
    var w = Math.max(1, Math.round(canvas.clientWidth * dpr)), h = Math.max(1, Math.round(canvas.clientHeight * dpr));
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
    return dpr;
  }
  function render() {
    pending = false;
    var dpr = resize();
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(1, 1, 1, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    var e = eye(), view = lookAt(e, cam.target, UP);
    var near = Math.max(cam.distance - 2 * RADIUS, cam.distance * 0.01), far = cam.distance + 2 * RADIUS;
    var mvp = mul(perspective(FOV, canvas.width / canvas.height, near, far), view);
    var light = norm(sub(e, cam.target));  // a headlight: what faces the viewer is lit
    gl.enable(gl.DEPTH_TEST);
    gl.depthMask(true);
    gl.disable(gl.BLEND);
    gl.disable(gl.CULL_FACE);

    gl.useProgram(pointProg);
    gl.uniformMatrix4fv(pointProg.u.uMVP, false, mvp);
    gl.uniform3fv(pointProg.u.uLight, light);
    gl.uniform1f(pointProg.u.uSize, ui.size * dpr);
    if (ui.points && n) {
      attrib(pointProg, "aPos", buf.pos);
      attrib(pointProg, "aColor", ui.byHull && pointLab ? buf.byHull : buf.own);
      attrib(pointProg, "aNormal", buf.nrm);
      gl.uniform1f(pointProg.u.uShade, pointNrm ? (pointCol && !ui.byHull ? 0.6 : 1.0) : 0.0);
      gl.drawArrays(gl.POINTS, 0, n);
    }
    if (ui.removed && buf.removed) {
      attrib(pointProg, "aPos", buf.removed);
      constant(pointProg, "aColor", REMOVED);
      constant(pointProg, "aNormal", [0, 0, 0]);
      gl.uniform1f(pointProg.u.uShade, 0.0);
      gl.uniform1f(pointProg.u.uSize, Math.max(1, ui.size * 0.75) * dpr);
      gl.drawArrays(gl.POINTS, 0, removedPos.length / 3);
    }

    var shown = hulls.filter(function (h) { return h.visible; });
    shown.sort(function (a, b) {  // far to near
      return dot(sub(b.center, e), sub(b.center, e)) < dot(sub(a.center, e), sub(a.center, e)) ? -1 : 1;
    });
    if (ui.hulls) {
      gl.useProgram(hullProg);
      gl.uniformMatrix4fv(hullProg.u.uMVP, false, mvp);
      gl.uniform3fv(hullProg.u.uLight, light);
      gl.uniform1f(hullProg.u.uAlpha, ui.alpha);
      gl.enable(gl.BLEND);
      gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
      gl.depthMask(false);
      gl.enable(gl.CULL_FACE);
      shown.forEach(function (h) {
        attrib(hullProg, "aPos", h.bPos);
        attrib(hullProg, "aNormal", h.bNrm);
        gl.uniform3fv(hullProg.u.uColor, h.color);
        gl.cullFace(gl.FRONT);  // a convex hull: its far side first, then its near side
        gl.drawArrays(gl.TRIANGLES, 0, h.pos.length / 3);
        gl.cullFace(gl.BACK);
        gl.drawArrays(gl.TRIANGLES, 0, h.pos.length / 3);
      });
      gl.disable(gl.CULL_FACE);
    }
    if (ui.edges) {
      gl.useProgram(lineProg);
      gl.uniformMatrix4fv(lineProg.u.uMVP, false, mvp);
      gl.uniform1f(lineProg.u.uAlpha, 0.85);
      gl.enable(gl.BLEND);
      gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
      gl.depthMask(false);
      shown.forEach(function (h) {
        if (!h.lines.length) return;
        attrib(lineProg, "aPos", h.bLines);
        gl.uniform3fv(lineProg.u.uColor, h.color.map(function (x) { return 0.55 * x; }));
        gl.drawArrays(gl.LINES, 0, h.lines.length / 3);
      });
    }
    gl.depthMask(true);
    canvas.setAttribute("data-frames", String(1 + (parseInt(canvas.getAttribute("data-frames") || "0", 10))));
  }

  // ------------------------------------------------------------------ mouse, touch, keys
  var drag = null;
  canvas.addEventListener("contextmenu", function (ev) { ev.preventDefault(); });
  canvas.addEventListener("pointerdown", function (ev) {
    drag = { x: ev.clientX, y: ev.clientY, pan: ev.button === 2 || ev.button === 1 || ev.shiftKey };
    canvas.setPointerCapture(ev.pointerId);
  });
  canvas.addEventListener("pointermove", function (ev) {
    if (!drag) return;
    var dx = ev.clientX - drag.x, dy = ev.clientY - drag.y;
    drag.x = ev.clientX; drag.y = ev.clientY;
    if (drag.pan) {
      var e = eye(), z = norm(sub(e, cam.target)), x = norm(cross(UP, z)), y = cross(z, x);
      var k = 2 * cam.distance * Math.tan(FOV / 2) / canvas.clientHeight;
      for (var i = 0; i < 3; i++) cam.target[i] += (-dx * x[i] + dy * y[i]) * k;
    } else {
      cam.azimuth -= dx * 0.008;
      cam.elevation = Math.max(-1.55, Math.min(1.55, cam.elevation + dy * 0.008));
    }
    draw();
  });
  canvas.addEventListener("pointerup", function () { drag = null; });
  canvas.addEventListener("pointercancel", function () { drag = null; });
  canvas.addEventListener("wheel", function (ev) {
    ev.preventDefault();
    cam.distance = Math.max(RADIUS * 0.05, Math.min(RADIUS * 50, cam.distance * Math.exp(ev.deltaY * 0.0015)));
    draw();
  }, { passive: false });
  canvas.addEventListener("dblclick", function () { resetCamera(); draw(); });
  window.addEventListener("keydown", function (ev) {
    var keys = { p: "show-points", h: "show-hulls", e: "show-edges", g: "show-removed", c: "by-hull" };
    if (ev.key === "r") { resetCamera(); draw(); return; }
    var box = document.getElementById(keys[ev.key]);
    if (box && box.offsetParent !== null) { box.checked = !box.checked; box.dispatchEvent(new Event("change")); }
  });
  window.addEventListener("resize", draw);
  draw();
})();
