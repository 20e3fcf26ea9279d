/* modalfem modal runtime in JavaScript: exact per-mode damped oscillators, surface impulses and modal
 * sound. The same physics as modalfem/runtime/integrator.py (transition) and
 * modalfem/runtime/sound.py (monopole radiation of the listener-facing surface), for pages that run
 * without Python. No dependencies; loads as a classic script (global ModalRuntime) or in node
 * (module.exports).
 *
 * Units: the modal weights w_i [m] of a glTF from `modalfem export` (mode i scaled to a peak
 * displacement of 1 m, modal mass m_i [kg]) obey  w'' + mu w' + omega^2 w = (t_i(p) . F) / m_i,
 * omega [rad/s], mu [1/s]. Any other consistent scaling works the same (mass-normalised modes:
 * m_i = 1).
 */
(function (root, factory) {
  if (typeof module === 'object' && module.exports) module.exports = factory();
  else root.ModalRuntime = factory();
}(typeof self !== 'undefined' ? self : this, function () {
  'use strict';

  var AIR_DENSITY = 1.2;      // [kg/m^3], as modalfem.runtime.sound
  var F_MAX_HZ = 20000.0;     // band limit [Hz], as modalfem.runtime.synthesis

  function sinc(x) {          // sin(x) / x, exact near 0
    if (Math.abs(x) < 1e-4) return 1.0 - x * x / 6.0;
    return Math.sin(x) / x;
  }

  function sinhc(x) {         // sinh(x) / x, accurate near 0
    if (Math.abs(x) < 1e-3) return 1.0 + x * x / 6.0 + Math.pow(x, 4) / 120.0;
    return Math.sinh(x) / x;
  }

  /* Exact homogeneous one-step coefficients of y'' + mu y' + lam y = 0 over a step h [s]:
   * y1 = a11 y0 + a12 v0, v1 = a21 y0 + a22 v0, in every regime (underdamped, critical,
   * overdamped, lam = 0), written as modalfem.runtime.integrator.transition does (no overflow for
   * any h, no cancellation near critical damping). lam = omega^2 [rad^2/s^2], mu [1/s]. */
  function transition1(lam, mu, h) {
    var a = 0.5 * mu, d = lam - a * a, C, S;
    if (d > 0) {
      var w = Math.sqrt(d), ea = Math.exp(-a * h);
      C = ea * Math.cos(w * h);
      S = ea * h * sinc(w * h);
    } else {
      var k = Math.sqrt(-d), apk = a + k;
      var s1 = apk > 0 ? -lam / apk : 0.0;
      var e1 = Math.exp(s1 * h), kh = k * h, ratio;
      C = e1 * 0.5 * (1.0 + Math.exp(-2.0 * kh));
      if (kh > 1e-3) ratio = -Math.expm1(-2.0 * kh) / (2.0 * k);
      else ratio = h * Math.exp(-kh) * sinhc(kh);
      S = e1 * ratio;
    }
    return [C + a * S, S, -lam * S, C - a * S];
  }

  /* Coefficient arrays (Float64Array each) for all modes. */
  function transition(lam, mu, h) {
    if (!(h > 0) || !isFinite(h)) throw new Error('time step must be finite and > 0 s, got ' + h);
    var r = lam.length, out = [new Float64Array(r), new Float64Array(r), new Float64Array(r), new Float64Array(r)];
    for (var i = 0; i < r; i++) {
      var c = transition1(lam[i], mu[i], h);
      out[0][i] = c[0]; out[1][i] = c[1]; out[2][i] = c[2]; out[3][i] = c[3];
    }
    return out;
  }

  /* r decoupled modes: weights w [m] and rates v [m/s]; omega [rad/s], mu [1/s], masses [kg]. */
  function ModalState(omega, mu, masses) {
    var r = omega.length;
    this.omega = Float64Array.from(omega);
    this.lam = this.omega.map(function (x) { return x * x; });
    this.mu = Float64Array.from(mu);
    this.masses = masses ? Float64Array.from(masses) : new Float64Array(r).fill(1.0);
    this.w = new Float64Array(r);
    this.v = new Float64Array(r);
    this.time = 0.0;
    this._cache = new Map();
  }
  ModalState.prototype.coefficients = function (dt) {
    var c = this._cache.get(dt);
    if (!c) {
      if (this._cache.size >= 8) this._cache.delete(this._cache.keys().next().value);
      c = transition(this.lam, this.mu, dt);
      this._cache.set(dt, c);
    }
    return c;
  };
  /* Advance by dt [s] exactly (free motion). */
  ModalState.prototype.step = function (dt) {
    var c = this.coefficients(dt), w = this.w, v = this.v;
    for (var i = 0; i < w.length; i++) {
      var w1 = c[0][i] * w[i] + c[1][i] * v[i];
      v[i] = c[2][i] * w[i] + c[3][i] * v[i];
      w[i] = w1;
    }
    this.time += dt;
  };
  /* Add a modal rate change dv (r,) [m/s] (an impulse). */
  ModalState.prototype.kick = function (dv) {
    for (var i = 0; i < this.v.length; i++) this.v[i] += dv[i];
  };
  ModalState.prototype.reset = function () { this.w.fill(0); this.v.fill(0); this.time = 0.0; };
  /* Mechanical energy sum m_i (v^2 + omega^2 w^2) / 2 [J]. */
  ModalState.prototype.energy = function () {
    var e = 0;
    for (var i = 0; i < this.w.length; i++) {
      e += 0.5 * this.masses[i] * (this.v[i] * this.v[i] + this.lam[i] * this.w[i] * this.w[i]);
    }
    return e;
  };
  ModalState.prototype.copy = function () {
    var s = new ModalState(this.omega, this.mu, this.masses);
    s.w.set(this.w); s.v.set(this.v); s.time = this.time;
    return s;
  };

  /* Modal rate change of an impulse J (3) [N s] at a surface point: triangle corners (3 vertex
   * indices), barycentric weights (3), targets: r arrays (Float32Array, 3 per vertex) in the same
   * axes as J. dv_i = (sum_k b_k t_i(v_k)) . J / m_i  [m/s]. */
  function impulseRates(targets, masses, corners, bary, J) {
    var r = targets.length, dv = new Float64Array(r);
    for (var i = 0; i < r; i++) {
      var t = targets[i], s = 0;
      for (var k = 0; k < 3; k++) {
        var o = 3 * corners[k];
        s += bary[k] * (t[o] * J[0] + t[o + 1] * J[1] + t[o + 2] * J[2]);
      }
      dv[i] = s / masses[i];
    }
    return dv;
  }

  /* Vertex vector areas (a third of the area-weighted outward normals around each vertex) of the
   * surface with vertices merged by identical position (crease copies are one vertex), as
   * modalfem.runtime.sound.vertex_vector_areas on the model's vertices. Returns {areas (3 per
   * vertex, per glTF vertex: the merged vertex's), key (merged index per vertex), count}. */
  function mergedVectorAreas(positions, indices) {
    var n = positions.length / 3, key = new Int32Array(n), seen = new Map(), count = 0;
    for (var v = 0; v < n; v++) {
      var id = positions[3 * v] + ',' + positions[3 * v + 1] + ',' + positions[3 * v + 2];
      var j = seen.get(id);
      if (j === undefined) { j = count++; seen.set(id, j); }
      key[v] = j;
    }
    var acc = new Float64Array(3 * count);
    for (var f = 0; f < indices.length; f += 3) {
      var a = indices[f], b = indices[f + 1], c = indices[f + 2];
      var ux = positions[3 * b] - positions[3 * a], uy = positions[3 * b + 1] - positions[3 * a + 1],
          uz = positions[3 * b + 2] - positions[3 * a + 2];
      var wx = positions[3 * c] - positions[3 * a], wy = positions[3 * c + 1] - positions[3 * a + 1],
          wz = positions[3 * c + 2] - positions[3 * a + 2];
      var nx = (uy * wz - uz * wy) / 6, ny = (uz * wx - ux * wz) / 6, nz = (ux * wy - uy * wx) / 6;
      for (var k = 0; k < 3; k++) {
        var m = key[indices[f + k]];
        acc[3 * m] += nx; acc[3 * m + 1] += ny; acc[3 * m + 2] += nz;
      }
    }
    return { areas: acc, key: key, count: count };
  }

  /* Radiation weights W_i = sum_v max(n_v . d, 0) (a_v . t_i(v)) [m^2] over the merged vertices,
   * d the unit listener direction in the targets' axes (modalfem.runtime.sound.listener_weights). */
  function radiationWeights(merged, targets, direction) {
    var d = direction, dn = Math.hypot(d[0], d[1], d[2]);
    var dx = d[0] / dn, dy = d[1] / dn, dz = d[2] / dn;
    var cnt = merged.count, a = merged.areas, f = new Float64Array(3 * cnt), rep = new Int32Array(cnt).fill(-1);
    for (var m = 0; m < cnt; m++) {
      var ax = a[3 * m], ay = a[3 * m + 1], az = a[3 * m + 2], an = Math.hypot(ax, ay, az);
      var facing = an > 0 ? Math.max(ax * dx + ay * dy + az * dz, 0) / an : 0;
      f[3 * m] = facing * ax; f[3 * m + 1] = facing * ay; f[3 * m + 2] = facing * az;
    }
    var key = merged.key;
    for (var v = 0; v < key.length; v++) if (rep[key[v]] < 0) rep[key[v]] = v;
    var W = new Float64Array(targets.length);
    for (var i = 0; i < targets.length; i++) {
      var t = targets[i], s = 0;
      for (var j = 0; j < cnt; j++) {
        var o = 3 * rep[j];
        s += f[3 * j] * t[o] + f[3 * j + 1] * t[o + 1] + f[3 * j + 2] * t[o + 2];
      }
      W[i] = s;
    }
    return W;
  }

  /* Sound pressure [Pa] at a listener at distance r [m] from the free motion of a modal state:
   * p(t) = rho_air / (4 pi r) sum_i W_i w_i''(t), w'' = -mu w' - omega^2 w, sampled exactly at
   * t = n / sampleRate (n = 0..count-1) by the per-sample transition. Modes at or above f_max
   * [Hz] or the Nyquist frequency, and overdamped ones (mu / 2 >= omega), are left out (as
   * modalfem.runtime.synthesis.band_limit). Returns Float32Array(count). */
  function renderPressure(state, W, opts) {
    opts = opts || {};
    var fs = opts.sampleRate || 44100, count = opts.count || Math.round((opts.duration || 2.0) * fs);
    var dist = opts.distance || 1.0, fmax = Math.min(opts.fMax || F_MAX_HZ, fs / 2);
    var out = new Float32Array(count), acc = new Float64Array(count), h = 1.0 / fs;
    var scale = AIR_DENSITY / (4 * Math.PI * dist);
    for (var i = 0; i < state.w.length; i++) {
      var om = state.omega[i], mu = state.mu[i];
      if (om / (2 * Math.PI) >= fmax || 0.5 * mu >= om || W[i] === 0) continue;
      var c = transition1(om * om, mu, h), y = state.w[i], v = state.v[i], g = scale * W[i], lam = om * om;
      if (y === 0 && v === 0) continue;
      for (var n = 0; n < count; n++) {
        acc[n] += g * (-mu * v - lam * y);
        var y1 = c[0] * y + c[1] * v;
        v = c[2] * y + c[3] * v;
        y = y1;
      }
    }
    for (var m = 0; m < count; m++) out[m] = acc[m];
    return out;
  }

  /* Seconds until the slowest-decaying audible mode has lost `db` decibels (at most `cap` s). */
  function ringTime(state, db, cap) {
    var t = 0;
    for (var i = 0; i < state.mu.length; i++) {
      if (state.v[i] === 0 && state.w[i] === 0) continue;
      var a = 0.5 * state.mu[i];
      t = Math.max(t, a > 0 ? db / 20 * Math.LN10 / a : Infinity);
    }
    return Math.min(t, cap);
  }

  return {
    AIR_DENSITY: AIR_DENSITY, F_MAX_HZ: F_MAX_HZ, transition1: transition1, transition: transition,
    ModalState: ModalState, impulseRates: impulseRates, mergedVectorAreas: mergedVectorAreas,
    radiationWeights: radiationWeights, renderPressure: renderPressure, ringTime: ringTime
  };
}));
