// modalfem live viewer page (served by modalfem.view.Viewer). WebGL2, no dependencies.
// Protocol: GET /scene (JSON), GET /body/<i> (binary: rest float32 (nv,3), triangles uint32 (nt,3),
// shapes float32 (r, 3 nv)), GET /events (Server-Sent Events: one JSON frame per message),
// POST /input (JSON: strike / control / button). A modal body's frame carries q; the page deforms
// x = X + Phi q itself (vertex shader). Other bodies' frames carry positions (base64 float32).
// window.modalfemViewer exposes the page's state (frames, bodies, strikes, sounds) to tests.
"use strict";

const V = window.modalfemViewer = {
  ready: false, framesReceived: 0, framesDrawn: 0, fps: 0, bodies: [], last: null,
  deforms: 0, deformMs: 0, soundsReceived: 0, soundsPlayed: 0, lastSound: null, errors: [], strikes: [],
};
window.addEventListener("error", (e) => V.errors.push(String(e.message)));

const canvas = document.getElementById("canvas");
const gl = canvas.getContext("webgl2", { antialias: true, preserveDrawingBuffer: true });
const statusEl = document.getElementById("status");
const messageEl = document.getElementById("message");
let statusText = "", audio = null, lastSoundId = null;

// ---------------------------------------------------------------------------- small 4x4 math (column-major)
function perspective(fovy, aspect, near, far) {
  const f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
  return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0]);
}
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const norm = (a) => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };
function lookAt(eye, target, up) {
  const z = norm(sub(eye, target)), x = norm(cross(up, z)), y = cross(z, x);
  return new Float32Array([x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
    -dot(x, eye), -dot(y, eye), -dot(z, eye), 1]);
}
function quatMatrix(p) {  // pose [px, py, pz, w, x, y, z] -> column-major 4x4
  const [px, py, pz, w, x, y, z] = p;
  return new Float32Array([
    1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y), 0,
    2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x), 0,
    2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y), 0, px, py, pz, 1]);
}
function toBody(M, p, isPoint) {  // inverse of a rigid 4x4 applied to a point or direction
  const d = isPoint ? [p[0] - M[12], p[1] - M[13], p[2] - M[14]] : p;
  return [M[0] * d[0] + M[1] * d[1] + M[2] * d[2], M[4] * d[0] + M[5] * d[1] + M[6] * d[2],
    M[8] * d[0] + M[9] * d[1] + M[10] * d[2]];
}

// ---------------------------------------------------------------------------- shaders
// A modal body is deformed here, on the GPU (as DyRT did): x = X + sum_i q_i phi_i and the
// linearised normal n = n0 + sum_i q_i dn_i, with phi and dn in float textures (one row block per
// mode) and q in a small texture updated per frame. Other bodies (and modal ones whose modes do not
// fit a texture) come with positions and normals computed on the CPU (uModes = 0).
const VS = `#version 300 es
in vec3 aPos; in vec3 aNrm; in float aDisp;
uniform mat4 uModel, uView, uProj; uniform float uDispScale;
uniform highp sampler2D uShapes, uDNrm, uQ; uniform int uModes, uCount, uWidth;
out vec3 vN; out vec3 vW; out float vD;
void main() {
  vec3 p = aPos, n = aNrm;
  for (int i = 0; i < uModes; i++) {
    float qi = texelFetch(uQ, ivec2(i, 0), 0).r;
    if (qi == 0.0) continue;
    int k = i * uCount + gl_VertexID;
    ivec2 t = ivec2(k % uWidth, k / uWidth);
    p += qi * texelFetch(uShapes, t, 0).xyz;
    n += qi * texelFetch(uDNrm, t, 0).xyz;
  }
  vec4 w = uModel * vec4(p, 1.0);
  vW = w.xyz; vN = mat3(uModel) * n;
  vD = (uModes > 0 ? length(p - aPos) : aDisp) * uDispScale;
  gl_Position = uProj * uView * w;
}`;
const FS = `#version 300 es
precision highp float;
in vec3 vN; in vec3 vW; in float vD;
uniform vec3 uEye, uColor; out vec4 o;
void main() {
  vec3 n = normalize(vN); if (!gl_FrontFacing) n = -n;
  vec3 l = normalize(uEye - vW);
  float d = max(dot(n, l), 0.0);
  vec3 base = mix(uColor, vec3(0.85, 0.18, 0.12), 0.8 * clamp(vD, 0.0, 1.0));
  o = vec4(base * (0.28 + 0.72 * d) + vec3(0.18) * pow(d, 40.0), 1.0);
}`;
function program() {
  const p = gl.createProgram();
  for (const [type, src] of [[gl.VERTEX_SHADER, VS], [gl.FRAGMENT_SHADER, FS]]) {
    const s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    gl.attachShader(p, s);
  }
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
  return p;
}

// ---------------------------------------------------------------------------- bodies
function makeBody(head, buf) {
  const nv = head.vertex_count, nt = head.triangle_count, r = head.mode_count;
  const rest = new Float32Array(buf, 0, 3 * nv);
  const tris = new Uint32Array(buf, 12 * nv, 3 * nt);
  const shapes = r ? new Float32Array(buf, 12 * nv + 12 * nt, r * 3 * nv) : null;
  const { orig, rtris } = splitCreases(rest, tris, nv);
  const nr = orig.length;
  const b = { head, nv, nt, r, rest, tris, shapes, cur: new Float32Array(rest), orig, rtris, nr,
    rpos: new Float32Array(3 * nr), nrm: new Float32Array(3 * nr), disp: new Float32Array(nr),
    q: new Float64Array(r), pose: [0, 0, 0, 1, 0, 0, 0], positions: null };
  let lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < nv; i++) for (let c = 0; c < 3; c++) {
    lo[c] = Math.min(lo[c], rest[3 * i + c]); hi[c] = Math.max(hi[c], rest[3 * i + c]);
  }
  b.lo = lo; b.hi = hi; b.size = Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) || 1;
  b.vao = gl.createVertexArray(); gl.bindVertexArray(b.vao);
  b.bufPos = gl.createBuffer(); b.bufNrm = gl.createBuffer(); b.bufDisp = gl.createBuffer();
  for (const [buffer, loc, n] of [[b.bufPos, 0, 3], [b.bufNrm, 1, 3], [b.bufDisp, 2, 1]]) {
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer); gl.bufferData(gl.ARRAY_BUFFER, 4 * n * nr, gl.DYNAMIC_DRAW);
    gl.enableVertexAttribArray(loc); gl.vertexAttribPointer(loc, n, gl.FLOAT, false, 0, 0);
  }
  const ib = gl.createBuffer(); gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ib);
  gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, rtris, gl.STATIC_DRAW);
  gl.bindVertexArray(null);
  b.gpu = r > 0 && modalTextures(b);
  if (b.gpu) {  // rest positions and normals once; per frame only q
    b.q.fill(0); cpuPositions(b); renderVertices(b);
    b.restBuffers = [[b.bufPos, b.rpos.slice()], [b.bufNrm, b.nrm.slice()]];
    b.buffersDeformed = true;
  }
  b.stale = true;
  return b;
}

function texture(unit, internal, format, w, h, data) {
  const t = gl.createTexture();
  gl.activeTexture(gl.TEXTURE0 + unit); gl.bindTexture(gl.TEXTURE_2D, t);
  for (const k of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, k, gl.NEAREST);
  for (const k of [gl.TEXTURE_WRAP_S, gl.TEXTURE_WRAP_T]) gl.texParameteri(gl.TEXTURE_2D, k, gl.CLAMP_TO_EDGE);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
  gl.texImage2D(gl.TEXTURE_2D, 0, internal, w, h, 0, format, gl.FLOAT, data);
  return t;
}

function modalTextures(b) {
  // phi_i and dn_i at the render vertices, texel i * nr + j of a (width x height) RGB32F texture
  const { r, nr, orig, shapes, nv, rest } = b, tris = b.rtris, max = gl.getParameter(gl.MAX_TEXTURE_SIZE);
  const width = Math.min(max, 4096), height = Math.ceil(r * nr / width);
  if (height > max || r > max) return false;
  const phi = new Float32Array(3 * width * height), dn = new Float32Array(3 * width * height);
  const x = new Float32Array(3 * nr);
  for (let j = 0; j < nr; j++) for (let c = 0; c < 3; c++) x[3 * j + c] = rest[3 * orig[j] + c];
  b.peak = new Float64Array(r);  // largest |phi_i| over the vertices: a bound for the colour scale
  for (let i = 0; i < r; i++) {
    const s = shapes.subarray(3 * nv * i, 3 * nv * (i + 1)), o = 3 * nr * i;
    for (let j = 0; j < nr; j++) {
      const v = 3 * orig[j];
      phi[o + 3 * j] = s[v]; phi[o + 3 * j + 1] = s[v + 1]; phi[o + 3 * j + 2] = s[v + 2];
      b.peak[i] = Math.max(b.peak[i], Math.hypot(s[v], s[v + 1], s[v + 2]));
    }
    for (let t = 0; t < tris.length; t += 3) {  // d/dq_i of cross(xb - xa, xc - xa), summed at the corners
      const a = 3 * tris[t], bb = 3 * tris[t + 1], c = 3 * tris[t + 2];
      const e1 = [x[bb] - x[a], x[bb + 1] - x[a + 1], x[bb + 2] - x[a + 2]];
      const e2 = [x[c] - x[a], x[c + 1] - x[a + 1], x[c + 2] - x[a + 2]];
      const d1 = [phi[o + bb] - phi[o + a], phi[o + bb + 1] - phi[o + a + 1], phi[o + bb + 2] - phi[o + a + 2]];
      const d2 = [phi[o + c] - phi[o + a], phi[o + c + 1] - phi[o + a + 1], phi[o + c + 2] - phi[o + a + 2]];
      const m = cross(d1, e2), n = cross(e1, d2);
      for (const k of [a, bb, c]) for (let q = 0; q < 3; q++) dn[o + k + q] += m[q] + n[q];
    }
  }
  b.texShapes = texture(0, gl.RGB32F, gl.RGB, width, height, phi);
  b.texDNrm = texture(1, gl.RGB32F, gl.RGB, width, height, dn);
  b.texQ = texture(2, gl.R32F, gl.RED, r, 1, new Float32Array(r));
  b.texWidth = width; b.q32 = new Float32Array(r);
  return gl.getError() === gl.NO_ERROR;
}

function cpuPositions(b) {  // cur = X + Phi q (modal) or the sent positions, at the surface vertices
  const { nv, rest, cur } = b;
  if (b.positions) { cur.set(b.positions); return; }
  cur.set(rest);
  for (let i = 0; i < b.r; i++) {
    const qi = b.q[i]; if (qi === 0) continue;
    const s = b.shapes.subarray(3 * nv * i, 3 * nv * (i + 1));
    for (let k = 0; k < 3 * nv; k++) cur[k] += qi * s[k];
  }
}

function renderVertices(b) {  // render-vertex positions, area-weighted normals and |u| from cur; the peak |u|
  const { rest, cur, nrm, disp, orig, rpos, nr } = b, tris = b.rtris;
  let peak = 0;
  for (let j = 0; j < nr; j++) {
    const i = 3 * orig[j];
    rpos[3 * j] = cur[i]; rpos[3 * j + 1] = cur[i + 1]; rpos[3 * j + 2] = cur[i + 2];
    // colour shows the modal deformation; a body without modes (sent positions) keeps its colour
    disp[j] = b.positions ? 0 : Math.hypot(cur[i] - rest[i], cur[i + 1] - rest[i + 1], cur[i + 2] - rest[i + 2]);
    peak = Math.max(peak, disp[j]);
  }
  nrm.fill(0);
  for (let t = 0; t < tris.length; t += 3) {
    const a = 3 * tris[t], bb = 3 * tris[t + 1], c = 3 * tris[t + 2];
    const ux = rpos[bb] - rpos[a], uy = rpos[bb + 1] - rpos[a + 1], uz = rpos[bb + 2] - rpos[a + 2];
    const vx = rpos[c] - rpos[a], vy = rpos[c + 1] - rpos[a + 1], vz = rpos[c + 2] - rpos[a + 2];
    const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    for (const k of [a, bb, c]) { nrm[k] += nx; nrm[k + 1] += ny; nrm[k + 2] += nz; }
  }
  return peak;
}

function splitCreases(rest, tris, nv) {
  // Render vertices: a surface vertex is split where its triangles meet at a crease (face normals
  // more than ~40 degrees apart at rest), so box edges stay sharp while curved surfaces are smooth.
  const nt = tris.length / 3, fn = new Float32Array(3 * nt), count = new Uint32Array(nv + 1);
  for (let t = 0; t < nt; t++) {
    const a = 3 * tris[3 * t], b = 3 * tris[3 * t + 1], c = 3 * tris[3 * t + 2];
    const n = norm(cross([rest[b] - rest[a], rest[b + 1] - rest[a + 1], rest[b + 2] - rest[a + 2]],
      [rest[c] - rest[a], rest[c + 1] - rest[a + 1], rest[c + 2] - rest[a + 2]]));
    fn.set(n, 3 * t);
    for (let k = 0; k < 3; k++) count[tris[3 * t + k] + 1]++;
  }
  for (let v = 0; v < nv; v++) count[v + 1] += count[v];
  const corners = new Uint32Array(3 * nt), fill = count.slice(0, nv);
  for (let c = 0; c < 3 * nt; c++) corners[fill[tris[c]]++] = c;
  const orig = [], rtris = new Uint32Array(3 * nt), cos = Math.cos(40 * Math.PI / 180);
  for (let v = 0; v < nv; v++) {
    const groups = [];  // [first triangle, render vertex]
    for (let j = count[v]; j < count[v + 1]; j++) {
      const c = corners[j], t = (c / 3) | 0;
      let g = groups.find(([s]) => fn[3 * s] * fn[3 * t] + fn[3 * s + 1] * fn[3 * t + 1] + fn[3 * s + 2] * fn[3 * t + 2] > cos);
      if (!g) { g = [t, orig.length]; groups.push(g); orig.push(v); }
      rtris[c] = g[1];
    }
  }
  return { orig: Uint32Array.from(orig), rtris };
}

function deform(b) {  // apply the newest frame: q to its texture (GPU path) or positions + normals (CPU)
  const t0 = performance.now();
  let peak;
  if (b.gpu && !b.positions) {
    if (b.buffersDeformed) {  // at first, or after frames with positions: rest data for the shader
      for (const [buffer, data] of b.restBuffers) { gl.bindBuffer(gl.ARRAY_BUFFER, buffer); gl.bufferSubData(gl.ARRAY_BUFFER, 0, data); }
      b.buffersDeformed = false;
    }
    for (let i = 0; i < b.r; i++) b.q32[i] = b.q[i];
    gl.activeTexture(gl.TEXTURE2); gl.bindTexture(gl.TEXTURE_2D, b.texQ);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, b.r, 1, gl.RED, gl.FLOAT, b.q32);
    peak = 0;
    for (let i = 0; i < b.r; i++) peak += Math.abs(b.q[i]) * b.peak[i];
    b.curStale = true;  // picking computes the surface on the CPU only when it needs it
  } else {
    cpuPositions(b);
    peak = renderVertices(b);
    b.buffersDeformed = true;
    for (const [buffer, data] of [[b.bufPos, b.rpos], [b.bufNrm, b.nrm], [b.bufDisp, b.disp]]) {
      gl.bindBuffer(gl.ARRAY_BUFFER, buffer); gl.bufferSubData(gl.ARRAY_BUFFER, 0, data);
    }
  }
  // colour scale: the largest displacement of the last second or so (peak hold with a slow decay)
  b.dispRef = Math.max(peak, 0.97 * (b.dispRef || 0), 1e-4 * b.size);
  b.stale = false;
  V.deforms++; V.deformMs += performance.now() - t0;
}

// ---------------------------------------------------------------------------- camera
const cam = { az: -0.9, el: 0.45, dist: 1, target: [0, 0, 0], fov: 0.7 };
function frameScene() {
  let lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (const b of V.bodies) for (let c = 0; c < 3; c++) {
    lo[c] = Math.min(lo[c], b.lo[c] + b.pose[c]); hi[c] = Math.max(hi[c], b.hi[c] + b.pose[c]);
  }
  cam.target = [0, 1, 2].map((c) => 0.5 * (lo[c] + hi[c]));
  const radius = 0.5 * Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
  cam.dist = 1.15 * radius / Math.sin(cam.fov / 2);
}
function eye() {
  const ce = Math.cos(cam.el);
  return [cam.target[0] + cam.dist * ce * Math.cos(cam.az), cam.target[1] + cam.dist * ce * Math.sin(cam.az),
    cam.target[2] + cam.dist * Math.sin(cam.el)];
}
function matrices() {
  const w = canvas.clientWidth, h = canvas.clientHeight, e = eye();
  return { e, view: lookAt(e, cam.target, [0, 0, 1]), proj: perspective(cam.fov, w / h, cam.dist * 0.01, cam.dist * 10) };
}

// ---------------------------------------------------------------------------- picking
function pick(px, py) {  // canvas pixel -> nearest hit {body, triangle, barycentric, direction} or null
  const w = canvas.clientWidth, h = canvas.clientHeight, e = eye();
  const f = norm(sub(cam.target, e)), right = norm(cross(f, [0, 0, 1])), up = cross(right, f);
  const t = Math.tan(cam.fov / 2), sx = (2 * px / w - 1) * t * w / h, sy = (1 - 2 * py / h) * t;
  const dir = norm([0, 1, 2].map((c) => f[c] + sx * right[c] + sy * up[c]));
  let best = null;
  for (const [bi, b] of V.bodies.entries()) {
    if (b.curStale) { cpuPositions(b); b.curStale = false; }
    const M = quatMatrix(b.pose), o = toBody(M, e, true), d = toBody(M, dir, false), x = b.cur;
    for (let k = 0; k < b.nt; k++) {  // Moller-Trumbore
      const i0 = 3 * b.tris[3 * k], i1 = 3 * b.tris[3 * k + 1], i2 = 3 * b.tris[3 * k + 2];
      const e1 = [x[i1] - x[i0], x[i1 + 1] - x[i0 + 1], x[i1 + 2] - x[i0 + 2]];
      const e2 = [x[i2] - x[i0], x[i2 + 1] - x[i0 + 1], x[i2 + 2] - x[i0 + 2]];
      const p = cross(d, e2), det = dot(e1, p);
      if (Math.abs(det) < 1e-30) continue;
      const s = [o[0] - x[i0], o[1] - x[i0 + 1], o[2] - x[i0 + 2]];
      const u = dot(s, p) / det; if (u < 0 || u > 1) continue;
      const qv = cross(s, e1), v = dot(d, qv) / det; if (v < 0 || u + v > 1) continue;
      const dist = dot(e2, qv) / det;
      if (dist > 0 && (!best || dist < best.distance)) {
        best = { body: bi, triangle: k, barycentric: [1 - u - v, u, v], direction: dir, distance: dist };
      }
    }
  }
  return best;
}
V.pick = pick;

async function post(msg) {
  const res = await fetch("/input", { method: "POST", headers: { "Content-Type": "application/json" },
    body: JSON.stringify(msg) });
  const out = await res.json();
  messageEl.textContent = res.ok ? "" : out.error;
  return out;
}
async function strikeAt(px, py) {
  if (!audio) audio = new AudioContext();
  if (audio.state === "suspended") audio.resume();
  const hit = pick(px, py);
  if (!hit) return null;
  const out = await post({ type: "strike", body: hit.body, triangle: hit.triangle, barycentric: hit.barycentric,
    direction: hit.direction });
  V.strikes.push({ hit, out });
  return out;
}
V.strikeAt = strikeAt;

let drag = null;
canvas.addEventListener("pointerdown", (e) => { drag = { x: e.offsetX, y: e.offsetY, moved: false }; canvas.setPointerCapture(e.pointerId); });
canvas.addEventListener("pointermove", (e) => {
  if (!drag) return;
  const dx = e.offsetX - drag.x, dy = e.offsetY - drag.y;
  if (!drag.moved && Math.hypot(dx, dy) < 4) return;
  drag.moved = true; drag.x = e.offsetX; drag.y = e.offsetY;
  cam.az -= dx * 0.008; cam.el = Math.max(-1.5, Math.min(1.5, cam.el + dy * 0.008));
});
canvas.addEventListener("pointerup", (e) => {
  if (drag && !drag.moved) strikeAt(e.offsetX, e.offsetY);
  drag = null;
});
canvas.addEventListener("wheel", (e) => { e.preventDefault(); cam.dist *= Math.exp(e.deltaY * 0.001); }, { passive: false });

// ---------------------------------------------------------------------------- sound
function playSound(s) {
  const bytes = Uint8Array.from(atob(s.pcm16), (c) => c.charCodeAt(0));
  const pcm = new Int16Array(bytes.buffer);
  const data = Float32Array.from(pcm, (v) => v / 32768);
  V.soundsReceived++;
  V.lastSound = { id: s.id, rate: s.rate, samples: data.length, peak: data.reduce((m, v) => Math.max(m, Math.abs(v)), 0) };
  if (!audio) return;
  const buffer = audio.createBuffer(1, data.length, s.rate);
  buffer.copyToChannel(data, 0);
  const src = audio.createBufferSource(); src.buffer = buffer; src.connect(audio.destination); src.start();
  V.soundsPlayed++;
}

// ---------------------------------------------------------------------------- controls
const controlEls = {};
function buildControls(controls) {
  const root = document.getElementById("controls");
  for (const c of controls) {
    let el;
    const label = document.createElement("label");
    label.textContent = c.label;
    if (c.kind === "slider") {
      el = document.createElement("input"); el.type = "range";
      el.min = c.min; el.max = c.max; el.step = c.step || "any"; el.value = c.value;
      el.addEventListener("input", () => post({ type: "control", name: c.name, value: Number(el.value) }));
    } else if (c.kind === "select") {
      el = document.createElement("select");
      c.options.forEach((o, i) => { const opt = document.createElement("option"); opt.value = i; opt.textContent = o; el.appendChild(opt); });
      el.value = c.value;
      el.addEventListener("change", () => post({ type: "control", name: c.name, value: Number(el.value) }));
    } else if (c.kind === "checkbox") {
      el = document.createElement("input"); el.type = "checkbox"; el.checked = c.value;
      el.addEventListener("change", () => post({ type: "control", name: c.name, value: el.checked }));
      label.prepend(el); root.appendChild(label); controlEls[c.name] = el; continue;
    } else {
      el = document.createElement("button"); el.textContent = c.label;
      el.addEventListener("click", () => post({ type: "button", name: c.name }));
      root.appendChild(el); controlEls[c.name] = el; continue;
    }
    el.id = "control-" + c.name; label.htmlFor = el.id;
    root.appendChild(label); root.appendChild(el); controlEls[c.name] = el;
  }
}
function showControlValues(values) {
  for (const [name, v] of Object.entries(values || {})) {
    const el = controlEls[name]; if (!el || el === document.activeElement) continue;
    if (el.type === "checkbox") el.checked = v; else if (String(el.value) !== String(v)) el.value = v;
  }
}

// ---------------------------------------------------------------------------- frames
function onFrame(f) {
  V.framesReceived++; V.last = f;
  f.bodies.forEach((fb, i) => {
    const b = V.bodies[i];
    if (fb.q) { b.q.set(fb.q); b.positions = null; b.stale = true; }
    if (fb.positions) {
      const bytes = Uint8Array.from(atob(fb.positions), (c) => c.charCodeAt(0));
      b.positions = new Float32Array(bytes.buffer); b.stale = true;
    }
    if (fb.pose) b.pose = fb.pose;
  });
  statusText = f.status || "";
  if (f.time !== null && f.time !== undefined) statusText += `   t = ${f.time.toPrecision(4)} s`;
  showControlValues(f.controls);
  if (f.sound) {
    if (lastSoundId === null) lastSoundId = f.sound.id;  // a clip from before this page loaded: not replayed
    else if (f.sound.id !== lastSoundId) { lastSoundId = f.sound.id; playSound(f.sound); }
  } else if (lastSoundId === null) lastSoundId = 0;
}

let fpsCount = 0, fpsT0 = performance.now();
function draw() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  gl.viewport(0, 0, w, h);
  gl.clearColor(0.125, 0.141, 0.165, 1); gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  const { e, view, proj } = matrices();
  gl.useProgram(V.prog);
  gl.uniformMatrix4fv(V.loc.uView, false, view); gl.uniformMatrix4fv(V.loc.uProj, false, proj);
  gl.uniform3fv(V.loc.uEye, e);
  for (const b of V.bodies) {
    if (b.stale) deform(b);
    gl.uniformMatrix4fv(V.loc.uModel, false, quatMatrix(b.pose));
    gl.uniform3fv(V.loc.uColor, b.head.color);
    gl.uniform1f(V.loc.uDispScale, 1 / b.dispRef);
    const gpu = b.gpu && !b.positions;
    gl.uniform1i(V.loc.uModes, gpu ? b.r : 0);
    gl.uniform1i(V.loc.uCount, b.nr); gl.uniform1i(V.loc.uWidth, gpu ? b.texWidth : 1);
    for (const [unit, tex] of [[0, gpu ? b.texShapes : V.dummy3], [1, gpu ? b.texDNrm : V.dummy3], [2, gpu ? b.texQ : V.dummy1]]) {
      gl.activeTexture(gl.TEXTURE0 + unit); gl.bindTexture(gl.TEXTURE_2D, tex);
    }
    gl.bindVertexArray(b.vao);
    gl.drawElements(gl.TRIANGLES, 3 * b.nt, gl.UNSIGNED_INT, 0);
  }
  V.framesDrawn++; fpsCount++;
  const now = performance.now();
  if (now - fpsT0 > 1000) { V.fps = 1000 * fpsCount / (now - fpsT0); fpsCount = 0; fpsT0 = now; }
  statusEl.textContent = `${statusText}   ${V.fps.toFixed(0)} fps`;
  requestAnimationFrame(draw);
}

async function main() {
  if (!gl) { statusEl.textContent = "this browser has no WebGL2"; return; }
  const scene = await (await fetch("/scene")).json();
  document.title = scene.title; document.getElementById("title").textContent = scene.title;
  V.prog = program();
  for (const [i, name] of ["aPos", "aNrm", "aDisp"].entries()) gl.bindAttribLocation(V.prog, i, name);
  gl.linkProgram(V.prog);
  V.loc = {};
  for (const u of ["uModel", "uView", "uProj", "uEye", "uColor", "uDispScale", "uShapes", "uDNrm", "uQ", "uModes",
    "uCount", "uWidth"]) V.loc[u] = gl.getUniformLocation(V.prog, u);
  gl.useProgram(V.prog);
  gl.uniform1i(V.loc.uShapes, 0); gl.uniform1i(V.loc.uDNrm, 1); gl.uniform1i(V.loc.uQ, 2);
  V.dummy3 = texture(0, gl.RGB32F, gl.RGB, 1, 1, new Float32Array(3));  // bound for bodies drawn without modes
  V.dummy1 = texture(2, gl.R32F, gl.RED, 1, 1, new Float32Array(1));
  for (const head of scene.bodies) {
    const buf = await (await fetch(`/body/${head.id}`)).arrayBuffer();
    V.bodies.push(makeBody(head, buf));
  }
  frameScene();
  buildControls(scene.controls);
  gl.enable(gl.DEPTH_TEST);
  const events = new EventSource("/events");
  events.onmessage = (m) => onFrame(JSON.parse(m.data));
  events.onerror = () => { statusText = "disconnected from the modalfem server"; };
  V.ready = true;
  requestAnimationFrame(draw);
}
main().catch((err) => { V.errors.push(String(err)); statusEl.textContent = "error: " + err; });
