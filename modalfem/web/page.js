/* modalfem export page: loads the embedded .glb (modes as morph targets) with three.js, integrates
 * the modes with ModalRuntime (modal.js) and drives the morph target influences; a click on the
 * surface strikes it (raycast -> triangle + barycentric point -> modal impulse) and plays its sound
 * through WebAudio. Needs the globals THREE (three.bundle.min.js) and ModalRuntime (modal.js), and
 * an element <script id="modalfem-glb" type="application/octet-stream"> holding the .glb in base64.
 *
 * window.modalfem exposes the running page for tests and for other tools:
 *   ready, error, frames, modeCount, state (visual, slow motion), audioState (real time),
 *   displayGain (morph influence per metre of weight; settable), timeScale (display seconds per
 *   second; 0 freezes the motion; settable), radius (of the rest shape [m]), strike({triangle, barycentric, impulse, listener}), strikeAt(x, y),
 *   lastSound (Float32Array of the last strike's pressure [Pa]), lastSoundRate, lastStrike.
 */
(function () {
  'use strict';
  var R = window.ModalRuntime;
  var api = window.modalfem = { ready: false, error: null, frames: 0, strikes: 0 };

  function fail(e) {
    api.error = String(e && e.message ? e.message : e);
    var el = document.getElementById('status');
    if (el) el.textContent = 'error: ' + api.error;
    console.error('modalfem page: ' + api.error);
  }

  function decodeBase64(text) {
    var bin = atob(text.replace(/\s+/g, '')), bytes = new Uint8Array(bin.length);
    for (var i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return bytes.buffer;
  }

  function fmt(x) { return x >= 100 ? x.toFixed(0) : x.toPrecision(3); }

  function start(gltf) {
    var extras = (gltf.userData || {}).modalfem;
    if (!extras) throw new Error('the glTF has no modalfem extras (not written by modalfem export)');
    var mesh = null;
    gltf.scene.traverse(function (o) { if (o.isMesh && !mesh) mesh = o; });
    if (!mesh) throw new Error('the glTF holds no mesh');
    var geom = mesh.geometry, k = extras.mode_count;
    var morph = geom.morphAttributes.position || [];
    if (morph.length !== k) throw new Error('the mesh has ' + morph.length + ' morph targets, extras say ' + k);
    var targets = morph.map(function (a) { return a.array; });
    var positions = geom.attributes.position.array, indices = geom.index.array;
    var merged = R.mergedVectorAreas(positions, indices);
    var state = new R.ModalState(extras.omega_rad_s, extras.damping_per_s, extras.mode_masses_kg);
    var audioState = state.copy();
    var f1 = extras.frequencies_hz[0];
    var timeScale = f1 > 1 ? 1.0 / f1 : 1.0;  // slow motion: the lowest mode turns once a second
    // the rest shape's bounds (three's own bounding sphere also encloses every morph target at weight 1)
    var sphere = new THREE.Box3().setFromBufferAttribute(geom.attributes.position).getBoundingSphere(new THREE.Sphere());
    var radius = sphere.radius, center = sphere.center.clone();

    var container = document.getElementById('view');
    var renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    renderer.setPixelRatio(window.devicePixelRatio || 1);
    renderer.setSize(container.clientWidth, container.clientHeight);
    container.appendChild(renderer.domElement);
    var scene = new THREE.Scene();
    scene.background = new THREE.Color(0x20242b);
    scene.add(new THREE.HemisphereLight(0xdde6ff, 0x3a3430, 1.6));
    var sun = new THREE.DirectionalLight(0xffffff, 2.2);
    sun.position.set(1, 2, 3);
    scene.add(sun);
    var fill = new THREE.DirectionalLight(0xffe8d0, 0.8);
    fill.position.set(-2, -1, 1);
    scene.add(fill);
    scene.add(gltf.scene);
    var camera = new THREE.PerspectiveCamera(35, container.clientWidth / container.clientHeight,
                                             radius / 100, radius * 100);
    camera.position.copy(center).add(new THREE.Vector3(0.9, 0.7, 1.6).normalize().multiplyScalar(radius * 4.4));
    camera.up.set(0, 0, 1);
    camera.lookAt(center);
    sun.position.copy(center).add(new THREE.Vector3(-1.2, 1.6, 1.0).multiplyScalar(radius * 4));  // raking: bends show in the shading
    var controls = new THREE.OrbitControls(camera, renderer.domElement);
    controls.target.copy(center);
    controls.update();

    var displayGain = 0;  // morph influence per metre of modal weight: set by the first strike
    var audioGain = 0, audioCtx = null, source = null, audioClock = null;
    var raycaster = new THREE.Raycaster();

    function info() {
      var f = extras.frequencies_hz;
      document.getElementById('info').textContent =
        k + ' modes, ' + fmt(f[0]) + '\u2013' + fmt(f[k - 1]) + ' Hz; motion slowed ' + fmt(1 / timeScale) +
        'x' + (displayGain > 0 ? ', displacements shown ' + displayGain.toPrecision(2) + 'x' : '') +
        '. Click the body to strike it; drag to turn.';
    }

    function objectDirection(worldDir) {  // a world direction in the mesh's axes (the targets' axes)
      var m = new THREE.Matrix3().setFromMatrix4(mesh.matrixWorld).invert();
      return worldDir.clone().applyMatrix3(m).normalize();
    }

    /* Strike: {triangle, barycentric [3], impulse [3] N s in mesh axes, listener [3] mesh axes}. */
    api.strike = function (s) {
      var tri = s.triangle, corners = [indices[3 * tri], indices[3 * tri + 1], indices[3 * tri + 2]];
      var dv = R.impulseRates(targets, state.masses, corners, s.barycentric, s.impulse);
      state.kick(dv);
      if (displayGain === 0) {  // peak displacement of the first strike shown as at most 15 % of the body's radius
        var bound = 0;
        for (var i = 0; i < k; i++) bound += Math.abs(dv[i]) / state.omega[i];
        displayGain = bound > 0 ? 0.15 * radius / bound : 0;
        info();
      }
      var now = performance.now() / 1000;
      if (audioClock !== null && now > audioClock) audioState.step(now - audioClock);
      audioClock = now;
      audioState.kick(dv);
      var rate = (audioCtx && audioCtx.sampleRate) || s.sampleRate || 44100;
      var W = R.radiationWeights(merged, targets, s.listener);
      var dur = Math.max(R.ringTime(audioState, 60, 4.0), 0.05);
      var p = R.renderPressure(audioState, W, { sampleRate: rate, duration: dur, distance: 1.0 });
      api.lastSound = p; api.lastSoundRate = rate;
      api.lastStrike = { triangle: tri, barycentric: Array.from(s.barycentric), impulse: Array.from(s.impulse),
                         listener: Array.from(s.listener), dv: Array.from(dv) };
      api.strikes += 1;
      play(p, rate);
      return api.lastStrike;
    };

    function play(p, rate) {
      if (!document.getElementById('sound').checked) return;
      try {
        if (!audioCtx) audioCtx = new (window.AudioContext || window.webkitAudioContext)();
        if (audioCtx.state === 'suspended') audioCtx.resume();
        var peak = 0;
        for (var i = 0; i < p.length; i++) peak = Math.max(peak, Math.abs(p[i]));
        if (audioGain === 0 && peak > 0) audioGain = 0.5 / peak;  // later strikes keep their loudness ratio
        var buf = audioCtx.createBuffer(1, p.length, rate), ch = buf.getChannelData(0);
        var fade = Math.min(p.length, Math.round(0.02 * rate));
        for (var n = 0; n < p.length; n++) {
          var g = n >= p.length - fade ? (p.length - n) / fade : 1;
          ch[n] = Math.max(-1, Math.min(1, audioGain * p[n] * g));
        }
        if (source) { try { source.stop(); } catch (e) { /* already ended */ } }
        source = audioCtx.createBufferSource();
        source.buffer = buf;
        source.connect(audioCtx.destination);
        source.start();
        api.audio = 'playing';
      } catch (e) {
        api.audio = 'unavailable: ' + e;
      }
    }

    /* Strike the surface under the canvas pixel (x, y) (CSS pixels from the canvas' top left). */
    api.strikeAt = function (x, y) {
      var rect = renderer.domElement.getBoundingClientRect();
      var ndc = new THREE.Vector2((x / rect.width) * 2 - 1, -(y / rect.height) * 2 + 1);
      raycaster.setFromCamera(ndc, camera);
      var hit = raycaster.intersectObject(mesh, false)[0];
      if (!hit) return null;
      var bary = hit.barycoord ? [hit.barycoord.x, hit.barycoord.y, hit.barycoord.z] : null;
      if (!bary) {
        var b = new THREE.Vector3();
        var tr = new THREE.Triangle();
        mesh.getVertexPosition(hit.face.a, tr.a); mesh.getVertexPosition(hit.face.b, tr.b);
        mesh.getVertexPosition(hit.face.c, tr.c);
        tr.a.applyMatrix4(mesh.matrixWorld); tr.b.applyMatrix4(mesh.matrixWorld); tr.c.applyMatrix4(mesh.matrixWorld);
        tr.getBarycoord(hit.point, b);
        bary = [b.x, b.y, b.z];
      }
      var dir = objectDirection(raycaster.ray.direction);
      var J = parseFloat(document.getElementById('impulse').value) || extras.mass_kg * 0.01;
      var toCamera = objectDirection(camera.position.clone().sub(hit.point));
      return api.strike({ triangle: hit.faceIndex, barycentric: bary, impulse: [dir.x * J, dir.y * J, dir.z * J],
                          listener: [toCamera.x, toCamera.y, toCamera.z] });
    };

    var down = null;
    renderer.domElement.addEventListener('pointerdown', function (e) { down = [e.clientX, e.clientY]; });
    renderer.domElement.addEventListener('pointerup', function (e) {
      if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 4) return;  // a drag turns the view
      var rect = renderer.domElement.getBoundingClientRect();
      api.strikeAt(e.clientX - rect.left, e.clientY - rect.top);
    });
    document.getElementById('reset').addEventListener('click', function () {
      state.reset(); audioState.reset(); audioClock = null;
      if (source) { try { source.stop(); } catch (e) { /* ended */ } }
    });
    document.getElementById('impulse').value = (extras.mass_kg * 0.01).toPrecision(2);
    window.addEventListener('resize', function () {
      camera.aspect = container.clientWidth / container.clientHeight;
      camera.updateProjectionMatrix();
      renderer.setSize(container.clientWidth, container.clientHeight);
    });

    var last = null, influences = mesh.morphTargetInfluences;
    function frame(t) {
      var now = t / 1000;
      if (last !== null && now > last && timeScale > 0) state.step(Math.min(now - last, 0.1) * timeScale);
      last = now;
      for (var i = 0; i < k; i++) influences[i] = displayGain * state.w[i];
      controls.update();
      renderer.render(scene, camera);
      api.frames += 1;
      requestAnimationFrame(frame);
    }
    api.radius = radius;
    api.state = state; api.audioState = audioState; api.modeCount = k; api.extras = extras;
    api.mesh = mesh; api.camera = camera; api.renderer = renderer;
    Object.defineProperty(api, 'displayGain', { get: function () { return displayGain; },
                                                set: function (x) { displayGain = x; info(); } });
    Object.defineProperty(api, 'timeScale', { get: function () { return timeScale; },
                                              set: function (x) { timeScale = x; info(); } });
    api.gl = renderer.getContext() instanceof WebGL2RenderingContext ? 'webgl2' : 'webgl1';
    info();
    document.getElementById('status').textContent = '';
    api.ready = true;
    requestAnimationFrame(frame);
  }

  try {
    var glb = decodeBase64(document.getElementById('modalfem-glb').textContent);
    new THREE.GLTFLoader().parse(glb, '', function (gltf) {
      try { start(gltf); } catch (e) { fail(e); }
    }, fail);
  } catch (e) {
    fail(e);
  }
}());
