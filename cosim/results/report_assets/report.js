// The report's page logic (cosim/results/report.py inlines it): builds the summary tables, the
// Plotly 3D scene and the linked Plotly plots from the embedded data, and keeps them on one
// timeline. All drawing is Plotly's; this file only arranges data and events.
(function () {
  'use strict';
  var D = JSON.parse(document.getElementById('cosim-data').textContent);
  var R = window.cosimReport = { ready: false, data: D, time: null, errors: [] };
  // the summary part (written last: summary.json's final status) joins the time-series part
  D.sources = D.light.sources;
  D.notes = D.light.notes.concat(D.notes);
  D.runs.forEach(function (r) {
    r.events = (D.light.run_events[r.label] || []).concat(r.bus_events || []).sort(function (a, b) { return a.time_s - b.time_s; });
    r.status = D.light.run_status[r.label] || (r.partial ? 'running' : null);
  });
  var t0 = performance.now();
  R.marks = { start: t0 };
  function mark(name) { R.marks[name] = performance.now() - t0; }

  // ---------------------------------------------------------------- decoding
  function bytes(b64) {
    var bin = atob(b64), n = bin.length, u = new Uint8Array(n);
    for (var i = 0; i < n; i++) u[i] = bin.charCodeAt(i);
    return u;
  }
  function typed(u8, dtype) {
    return dtype === 'f8' ? new Float64Array(u8.buffer, 0, u8.byteLength / 8)
                          : new Float32Array(u8.buffer, 0, u8.byteLength / 4);
  }
  function decode(p) { return p ? typed(bytes(p.b64), p.dtype) : null; }
  function uniform(p, a) {                // a time column: t0 + k dt plus each sample's residual (exact)
    if (!p.uniform) return a;
    var t0 = p.uniform[0], dt = p.uniform[1], out = new Float64Array(a.length);
    for (var k = 0; k < a.length; k++) out[k] = (t0 + k * dt) + a[k];
    return out;
  }
  function decodeAsync(p) {
    if (!p) return Promise.resolve(null);
    var u = bytes(p.b64);
    if (!p.z) return Promise.resolve(uniform(p, typed(u, p.dtype)));
    var stream = new Blob([u]).stream().pipeThrough(new DecompressionStream('deflate'));
    return new Response(stream).arrayBuffer().then(function (buf) {
      return uniform(p, typed(p.shuffle ? unshuffle(new Uint8Array(buf), p.dtype === 'f8' ? 8 : 4) : new Uint8Array(buf), p.dtype));
    });
  }
  function unshuffle(src, w) {             // byte k of every value, then byte k + 1 (report.py _pack) -> values
    var n = src.length / w, out = new Uint8Array(src.length);
    for (var b = 0; b < w; b++) { var o = b * n; for (var i = 0; i < n; i++) out[i * w + b] = src[o + i]; }
    return out;
  }
  var fullCache = new Map();
  function full(p) {                       // decoded once, on demand
    if (!p) return Promise.resolve(null);
    if (!fullCache.has(p)) fullCache.set(p, decodeAsync(p));
    return fullCache.get(p);
  }

  // ---------------------------------------------------------------- helpers
  function el(tag, attrs, text) {
    var e = document.createElement(tag);
    for (var k in (attrs || {})) e.setAttribute(k, attrs[k]);
    if (text !== undefined && text !== null) e.textContent = text;
    return e;
  }
  function fmt(v) {
    if (v === null || v === undefined) return '-';
    if (typeof v === 'number') {
      if (Number.isInteger(v) && Math.abs(v) < 1e9) return String(v);
      return Number(v.toPrecision(6)).toString();
    }
    if (typeof v === 'boolean') return v ? 'yes' : 'no';
    if (Array.isArray(v)) return v.map(fmt).join(', ');
    return String(v);
  }
  function dig(obj, key) {
    var parts = key.split('.');
    for (var i = 0; i < parts.length; i++) {
      if (obj === null || typeof obj !== 'object' || !(parts[i] in obj)) return undefined;
      obj = obj[parts[i]];
    }
    return obj;
  }
  function unitOf(key) {
    var m = /_(mm|rad|us|s|hz|m|kg|A|Nm|mrad|percent)$/.exec(key);
    return m ? ({ us: 'us', hz: 'Hz', percent: '%' }[m[1]] || m[1]) : '';
  }
  function nearest(t, x) {                 // index of the sample of sorted x nearest to t
    var lo = 0, hi = x.length - 1;
    if (hi < 0) return -1;
    while (hi - lo > 1) { var mid = (lo + hi) >> 1; if (x[mid] < t) lo = mid; else hi = mid; }
    return Math.abs(x[lo] - t) <= Math.abs(x[hi] - t) ? lo : hi;
  }
  function lowerBound(x, t) { var lo = 0, hi = x.length; while (lo < hi) { var m = (lo + hi) >> 1; if (x[m] < t) lo = m + 1; else hi = m; } return lo; }

  // ---------------------------------------------------------------- summary
  var runs = D.runs;
  var enabled = runs.map(function () { return true; });
  function badge(status) {
    var s = status || 'unknown';
    return el('span', { 'class': 'badge ' + (['ok', 'limit', 'fault', 'failed', 'interrupted', 'running'].indexOf(s) >= 0 ? s : 'unknown') }, s);
  }
  function figureCell(key, value) {
    var td = el('td', { 'class': 'fig', 'data-key': key, 'data-value': JSON.stringify(value === undefined ? null : value) }, fmt(value));
    return td;
  }
  function scalarTable(title, prefix, obj, into) {
    var rows = [];
    (function walk(o, path) {
      Object.keys(o).forEach(function (k) {
        var v = o[k], p = path ? path + '.' + k : k;
        if (v !== null && typeof v === 'object' && !Array.isArray(v)) walk(v, p);
        else if (v === null || typeof v !== 'object' || (Array.isArray(v) && v.length <= 8 && v.every(function (x) { return typeof x !== 'object'; })))
          rows.push([p, v]);
      });
    })(obj, '');
    if (!rows.length) return;
    into.appendChild(el('h3', {}, title));
    var table = el('table', { 'class': 'timing' });
    table.appendChild(el('tr')).append(el('th', {}, 'quantity'), el('th', {}, 'value'), el('th', {}, 'unit'));
    rows.forEach(function (r) {
      var tr = el('tr');
      tr.append(el('td', {}, r[0]), figureCell(prefix + r[0], r[1]), el('td', { 'class': 'unit' }, unitOf(r[0])));
      table.appendChild(tr);
    });
    into.appendChild(table);
  }
  function buildSummary() {
    var body = document.getElementById('summary-body'), line = document.getElementById('status-line');
    D.sources.forEach(function (src, si) {
      var S = src.summary || {};
      var box = el('div', { 'class': 'source', 'data-folder': src.folder });
      var head = el('p');
      head.append(el('b', {}, (S.scenario || src.name) + ' '), badge(S.status || (src.summary ? 'unknown' : 'unknown')),
        document.createTextNode(' job ' + (S.job || '?') + ', ' + fmt(S.sim_time_s) + ' s simulated in ' + fmt(S.wall_time_s)
          + ' s wall, folder ' + src.folder + (S.started_at ? ', started ' + S.started_at : '')));
      box.appendChild(head);
      if (si === 0) { line.innerHTML = ''; line.appendChild(badge(S.status)); line.appendChild(document.createTextNode(' ' + (S.description || ''))); }
      var mine = runs.filter(function (r) { return r.folder === src.folder; });
      var table = el('table', { 'class': 'figures' });
      var hr = el('tr'); hr.appendChild(el('th', {}, 'per mode / entry'));
      mine.forEach(function (r) { var th = el('th', {}, r.name); th.style.borderBottom = '3px solid ' + r.colour; hr.appendChild(th); });
      hr.appendChild(el('th', {}, 'unit'));
      table.appendChild(hr);
      var table_key = S.modes ? 'modes' : (S.entries ? 'entries' : null);
      D.key_figures.forEach(function (kf) {
        var values = mine.map(function (r) { return table_key ? dig(S, table_key + '.' + r.name + '.' + kf[0]) : undefined; });
        if (values.every(function (v) { return v === undefined; })) return;
        var tr = el('tr'); tr.appendChild(el('td', {}, kf[1]));
        mine.forEach(function (r, k) { tr.appendChild(values[k] === undefined ? el('td', {}, '') : figureCell(table_key + '.' + r.name + '.' + kf[0], values[k])); });
        tr.appendChild(el('td', { 'class': 'unit' }, kf[2]));
        table.appendChild(tr);
      });
      box.appendChild(table);
      var top = {};
      Object.keys(S).forEach(function (k) { if (typeof S[k] === 'number' && ['sim_time_s', 'wall_time_s'].indexOf(k) < 0) top[k] = S[k]; });
      if (S.reason) top.reason = S.reason;
      if (S.stopped_at_s !== undefined) top.stopped_at_s = S.stopped_at_s;
      scalarTable('Run', '', top, box);
      D.timing_keys.forEach(function (k) {
        if (S[k] && typeof S[k] === 'object') scalarTable('Timing report: ' + k, k + '.', S[k], box);
        mine.forEach(function (r) {
          var e = table_key ? dig(S, table_key + '.' + r.name + '.' + k) : undefined;
          if (e && typeof e === 'object') scalarTable('Timing report: ' + k + ' (' + r.name + ')', table_key + '.' + r.name + '.' + k + '.', e, box);
        });
      });
      if (src.compare && src.compare.rows) {
        box.appendChild(el('h3', {}, 'Ranking (by ' + (src.compare.rank_by || '?') + ', per trajectory)'));
        var cols = src.compare.columns ? Object.keys(src.compare.columns) : Object.keys(src.compare.rows[0] || {});
        var rt = el('table', { 'class': 'ranking' }), h = el('tr');
        cols.forEach(function (c) { h.appendChild(el('th', {}, src.compare.columns ? src.compare.columns[c] : c)); });
        rt.appendChild(h);
        src.compare.rows.forEach(function (row) {
          var tr = el('tr', { 'class': row.rank === 1 ? 'rank1' : '' });
          cols.forEach(function (c) { tr.appendChild(el('td', {}, fmt(row[c]))); });
          rt.appendChild(tr);
        });
        box.appendChild(rt);
      }
      if (src.figures && src.figures.length) {
        var fig = el('details', { 'class': 'figures' });
        fig.appendChild(el('summary', {}, 'The run\'s figures (' + src.figures.map(function (f) { return f.name; }).join(', ') + ')'));
        src.figures.forEach(function (f) {
          var img = el('img', { alt: f.name, title: f.name, src: 'data:image/png;base64,' + f.b64 });
          img.style.maxWidth = '48%'; img.style.margin = '0.3em'; img.style.verticalAlign = 'top';
          fig.appendChild(img);
        });
        box.appendChild(fig);
      }
      body.appendChild(box);
    });
    var notes = document.getElementById('notes');
    D.notes.forEach(function (n) { notes.appendChild(el('div', { 'class': 'note' }, n)); });
  }

  // ---------------------------------------------------------------- timeline
  var tMin = Infinity, tMax = -Infinity;
  runs.forEach(function (r) { Object.keys(r.times).forEach(function (s) { tMin = Math.min(tMin, r.times[s].t0); tMax = Math.max(tMax, r.times[s].t1); }); });
  if (!isFinite(tMin)) { tMin = 0; tMax = 1; }
  var slider = document.getElementById('timeline');
  slider.min = tMin; slider.max = tMax; slider.value = tMin;

  // ---------------------------------------------------------------- 2D plots
  var plots = [];          // {panel, div, traces: [{run, joint, curve, ox, oy}], joint, box}
  var axisLock = false, currentRange = null;
  function baseLayout(panel) {
    return {
      title: { text: panel.title, font: { size: 13 }, x: 0.01, xanchor: 'left' },
      margin: { l: 62, r: 12, t: 30, b: 30 }, showlegend: false, hovermode: 'x',
      xaxis: { title: { text: '' }, range: [tMin, tMax], showspikes: false, zeroline: false },
      yaxis: { title: { text: panel.ylabel, font: { size: 11 } }, type: panel.log ? 'log' : 'linear', exponentformat: 'power' },
      shapes: []
    };
  }
  function visibleFor(p, tr) {
    if (!enabled[tr.run]) return false;
    return !tr.joint || p.joint === 0 || tr.joint === p.joint;
  }
  function limitShapes(p) {
    var shapes = [];
    if (p.panel.limit && D.limits[p.panel.limit] && p.joint) {
      var v = D.limits[p.panel.limit].value[p.joint - 1];
      [v, -v].forEach(function (y) { shapes.push({ type: 'line', xref: 'paper', x0: 0, x1: 1, y0: y, y1: y, line: { color: '#d62728', dash: 'dash', width: 1.2 } }); });
    }
    var drawn = {};
    p.traces.forEach(function (tr) {         // a per-run limit of the series' file (e.g. the overrun tolerance)
      var v = tr.curve.limit;
      if (typeof v !== 'number' || !visibleFor(p, tr) || drawn[v]) return;
      drawn[v] = true;
      shapes.push({ type: 'line', xref: 'paper', x0: 0, x1: 1, y0: v, y1: v, name: 'limit',
                    line: { color: '#d62728', dash: 'dash', width: 1.2 },
                    label: { text: (p.panel.limit_label || 'limit') + ' ' + fmt(v) + ' ' + p.panel.unit,
                             textposition: 'end', yanchor: 'bottom', font: { size: 10, color: '#d62728' } } });
    });
    if (p.panel.key === 'compute') {
      runs.forEach(function (r, k) {
        var src = D.sources.find(function (s) { return s.folder === r.folder; }), S = (src && src.summary) || {};
        var b = dig(S, (S.modes ? 'modes.' : 'entries.') + r.name + '.compute_budget_us');
        if (typeof b === 'number' && enabled[k]) shapes.push({ type: 'line', xref: 'paper', x0: 0, x1: 1, y0: b, y1: b, line: { color: '#555', dash: 'dot', width: 1 } });
      });
    }
    return shapes;
  }
  function buildPlots() {
    var holder = document.getElementById('plots');
    var promises = [];
    D.panels.forEach(function (panel) {
      var traces = [], data = [];
      runs.forEach(function (r, k) {
        (r.series[panel.key] || []).forEach(function (c) {
          var ox = decode(c.ox), oy = decode(c.oy);
          traces.push({ run: k, joint: c.joint, curve: c, ox: ox, oy: oy, shown: 'overview' });
          data.push({ type: 'scatter', mode: 'lines', x: ox, y: oy, name: r.label + (c.joint ? ' axis ' + c.joint : ''),
                      line: { color: r.colour, width: 1.1, dash: c.joint && panel.joints.length ? 'solid' : 'solid' },
                      hovertemplate: '%{y:.6g} ' + panel.unit + '<extra>' + r.label + (c.joint ? ' axis ' + c.joint : '') + '</extra>' });
        });
      });
      if (!traces.length) return;
      var box = el('div', { 'class': 'panel', 'data-panel': panel.key });
      var p = { panel: panel, traces: traces, joint: panel.joints.length ? 1 : 0, box: box };
      if (panel.joints.length) {
        var bar = el('div', { 'class': 'joints' });
        bar.appendChild(document.createTextNode('axis: '));
        panel.joints.concat([0]).forEach(function (j) {
          var b = el('button', { type: 'button', 'data-joint': String(j), 'class': j === p.joint ? 'on' : '' }, j ? String(j) : 'all');
          b.addEventListener('click', function () { setJoint(p, j); });
          bar.appendChild(b);
        });
        box.appendChild(bar);
      }
      var res = el('span', { 'class': 'res' }, '');
      p.res = res;
      if (box.firstChild) box.firstChild.appendChild(res); else box.appendChild(res);
      var div = el('div', { 'class': 'plot', id: 'plot-' + panel.key });
      box.appendChild(div);
      var cursor = el('div', { 'class': 'cursor' });
      box.appendChild(cursor);
      p.div = div; p.cursor = cursor;
      holder.appendChild(box);
      traces.forEach(function (tr, i) { data[i].visible = visibleFor(p, tr); });
      var layout = baseLayout(panel);
      layout.shapes = limitShapes(p);
      plots.push(p);
      var before = performance.now();
      var made = Plotly.newPlot(div, data, layout, { responsive: true, displaylogo: false, scrollZoom: true });
      R.marks['newPlot ' + panel.key] = performance.now() - before;
      promises.push(made.then(function () {
        div.on('plotly_relayout', function (ev) { onRelayout(p, ev); });
        div.on('plotly_click', function (ev) { if (ev.points && ev.points.length) setTime(Number(ev.points[0].x)); });
      }));
      resolution(p);
    });
    return Promise.all(promises);
  }
  function setJoint(p, j) {
    p.joint = j;
    p.box.querySelectorAll('.joints button').forEach(function (b) { b.className = Number(b.getAttribute('data-joint')) === j ? 'on' : ''; });
    Plotly.update(p.div, { visible: p.traces.map(function (tr) { return visibleFor(p, tr); }) }, { shapes: limitShapes(p) });
    placeCursors();
  }
  function resolution(p) {
    var kinds = p.traces.filter(function (tr) { return visibleFor(p, tr); }).map(function (tr) { return tr.shown; });
    var fullN = kinds.filter(function (k) { return k === 'full'; }).length;
    var missing = p.traces.some(function (tr) { return !tr.curve.full; });
    p.res.textContent = fullN ? (fullN === kinds.length ? 'every sample shown' : fullN + ' of ' + kinds.length + ' curves at every sample')
      : 'min/max per ' + (kinds.length ? 'column' : '-') + (missing ? ' (some curves embedded decimated only)' : ' (zoom in for every sample)');
  }
  function onRelayout(p, ev) {
    if (axisLock) return;
    var range = null;
    if (ev['xaxis.range[0]'] !== undefined) range = [Number(ev['xaxis.range[0]']), Number(ev['xaxis.range[1]'])];
    else if (ev['xaxis.range']) range = [Number(ev['xaxis.range'][0]), Number(ev['xaxis.range'][1])];
    else if (ev['xaxis.autorange']) range = [tMin, tMax];
    if (!range) return;
    setRange(range, p);
  }
  function setRange(range, from) {
    currentRange = range;
    axisLock = true;
    var jobs = plots.map(function (q) {
      return (q === from ? Promise.resolve() : Plotly.relayout(q.div, { 'xaxis.range': range.slice(), 'xaxis.autorange': false }))
        .then(function () { return refine(q, range); });
    });
    return Promise.all(jobs).then(function () {
      axisLock = false;
      var t = R.time;
      if (t === null || t < range[0] || t > range[1]) setTime((range[0] + range[1]) / 2);
      else placeCursors();
    }, function (e) { axisLock = false; throw e; });
  }
  var ZOOM_POINTS = 4000;
  function refine(p, range) {            // every sample of the window, or min/max per column of it
    var whole = range[0] <= tMin + 1e-12 && range[1] >= tMax - 1e-12;
    var jobs = p.traces.map(function (tr) {
      if (whole || !tr.curve.full) {
        if (tr.shown === 'overview') return null;
        tr.shown = 'overview';
        return { x: tr.ox, y: tr.oy };
      }
      var r = runs[tr.run];
      return Promise.all([full(r.times[tr.curve.source].full), full(tr.curve.full)]).then(function (xy) {
        var x = xy[0], y = xy[1], a = lowerBound(x, range[0]), b = Math.min(x.length, lowerBound(x, range[1]) + 1);
        a = Math.max(0, a - 1);
        if (b - a <= ZOOM_POINTS) { tr.shown = 'full'; return { x: x.subarray(a, b), y: y.subarray(a, b) }; }
        tr.shown = 'window';
        return minMax(x, y, a, b, ZOOM_POINTS / 2);
      });
    });
    return Promise.all(jobs).then(function (out) {
      var idx = [], xs = [], ys = [];
      out.forEach(function (o, i) { if (o) { idx.push(i); xs.push(o.x); ys.push(o.y); } });
      resolution(p);
      if (idx.length) return Plotly.restyle(p.div, { x: xs, y: ys }, idx);
    });
  }
  function minMax(x, y, a, b, columns) {  // the first min and max of each column of [a, b), in order
    var xs = [], ys = [], span = x[b - 1] - x[a] || 1, col = -1, iMin = -1, iMax = -1;
    function flush() { if (iMin < 0) return; var p = iMin < iMax ? [iMin, iMax] : (iMin > iMax ? [iMax, iMin] : [iMin]); p.forEach(function (i) { xs.push(x[i]); ys.push(y[i]); }); }
    for (var i = a; i < b; i++) {
      var c = Math.min(columns - 1, Math.floor((x[i] - x[a]) / span * columns));
      if (c !== col) { flush(); col = c; iMin = iMax = -1; }
      var v = y[i];
      if (v !== v) continue;
      if (iMin < 0 || v < y[iMin]) iMin = i;
      if (iMax < 0 || v > y[iMax]) iMax = i;
    }
    flush();
    return { x: xs, y: ys };
  }
  function placeCursors() {
    plots.forEach(function (p) {
      var fl = p.div._fullLayout;
      if (!fl || !fl.xaxis || R.time === null) { p.cursor.style.display = 'none'; return; }
      var xa = fl.xaxis, px = xa.l2p(R.time);
      if (!(px >= 0 && px <= xa._length)) { p.cursor.style.display = 'none'; return; }
      p.cursor.style.display = 'block';
      p.cursor.style.left = (p.div.offsetLeft + fl._size.l + px) + 'px';
      p.cursor.style.top = (p.div.offsetTop + fl._size.t) + 'px';
      p.cursor.style.height = fl._size.h + 'px';
    });
  }

  // ---------------------------------------------------------------- 3D scene
  function matMul(a, b) {
    var c = new Array(16);
    for (var i = 0; i < 4; i++) for (var j = 0; j < 4; j++) {
      var s = 0; for (var k = 0; k < 4; k++) s += a[i * 4 + k] * b[k * 4 + j]; c[i * 4 + j] = s;
    }
    return c;
  }
  function transform(xyz, rpy) {            // URDF origin: translation, then R = Rz(yaw) Ry(pitch) Rx(roll)
    var cr = Math.cos(rpy[0]), sr = Math.sin(rpy[0]), cp = Math.cos(rpy[1]), sp = Math.sin(rpy[1]), cy = Math.cos(rpy[2]), sy = Math.sin(rpy[2]);
    return [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr, xyz[0],
            sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr, xyz[1],
            -sp, cp * sr, cp * cr, xyz[2], 0, 0, 0, 1];
  }
  function axisRotation(u, a) {             // Rodrigues
    var c = Math.cos(a), s = Math.sin(a), t = 1 - c, x = u[0], y = u[1], z = u[2];
    return [t * x * x + c, t * x * y - s * z, t * x * z + s * y, 0,
            t * x * y + s * z, t * y * y + c, t * y * z - s * x, 0,
            t * x * z - s * y, t * y * z + s * x, t * z * z + c, 0, 0, 0, 0, 1];
  }
  var chainStatic = D.urdf.chain.map(function (j) { return transform(j.xyz, j.rpy); });
  function linkFrames(q) {                  // the pose of each joint's parent link (base_link first)
    var T = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1], frames = [], qi = 0;
    D.urdf.chain.forEach(function (j, i) {
      frames.push(T);
      T = matMul(T, chainStatic[i]);
      if (j.type === 'revolute' || j.type === 'continuous') T = matMul(T, axisRotation(j.axis, q[qi++] || 0));
    });
    return frames;
  }
  var solids = D.urdf.solids;
  function armSolids(q) {                   // every link's cylinder (report.py link_solids) moved by its frame at q
    var frames = linkFrames(q), x = [], y = [], z = [];
    solids.links.forEach(function (s) {
      var T = frames[s.chain_index], v = s.vertices;
      for (var n = 0; n < v.length; n += 3) {
        x.push(T[0] * v[n] + T[1] * v[n + 1] + T[2] * v[n + 2] + T[3]);
        y.push(T[4] * v[n] + T[5] * v[n + 1] + T[6] * v[n + 2] + T[7]);
        z.push(T[8] * v[n] + T[9] * v[n + 1] + T[10] * v[n + 2] + T[11]);
      }
    });
    return [x, y, z];
  }
  function armFaces() {                     // one link's triangles, repeated for each link; shaded link by link
    var f = { i: [], j: [], k: [], facecolor: [] }, m = solids.per_link;
    solids.links.forEach(function (s, l) {
      for (var n = 0; n < solids.i.length; n++) {
        f.i.push(solids.i[n] + l * m); f.j.push(solids.j[n] + l * m); f.k.push(solids.k[n] + l * m);
      }
    });
    return f;
  }
  function shade(hex, amount) {             // a run's colour lighter (amount > 0) or darker, for alternate links
    if (!/^#[0-9a-f]{6}$/i.test(hex)) return hex;
    var c = parseInt(hex.slice(1), 16), out = [16, 8, 0].map(function (b) {
      var v = (c >> b) & 255; return Math.round(amount > 0 ? v + (255 - v) * amount : v * (1 + amount));
    });
    return 'rgb(' + out.join(',') + ')';
  }
  var scene = document.getElementById('scene'), sceneTraces = { arm: [], cursor: [] };
  var armData = runs.map(function (r) {
    if (!r.arm) return null;
    return { t: decode(r.arm.t), q: decode(r.arm.q) };
  });
  var pathData = runs.map(function (r) {
    if (!r.path) return null;
    return { t: decode(r.path.t), m: decode(r.path.measured), e: decode(r.path.err), p: r.path.programmed ? decode(r.path.programmed) : null };
  });
  function split3(a) { var x = [], y = [], z = []; for (var i = 0; i + 2 < a.length; i += 3) { x.push(a[i]); y.push(a[i + 1]); z.push(a[i + 2]); } return [x, y, z]; }
  function buildScene() {
    var data = [], lo = Infinity, hi = -Infinity;
    pathData.forEach(function (p) { if (p) for (var i = 0; i < p.e.length; i++) { var v = p.e[i]; if (v > 0 && isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); } } });
    var cmin = isFinite(lo) ? Math.log10(lo) : -3, cmax = isFinite(hi) ? Math.log10(hi) : 1;
    if (cmax - cmin < 1e-9) cmax = cmin + 1;
    var ticks = []; for (var d = Math.floor(cmin); d <= Math.ceil(cmax); d++) ticks.push(d);
    var programmedDone = false, colorbarDone = false;
    runs.forEach(function (r, k) {
      var p = pathData[k];
      if (p && p.p && !programmedDone) {
        var xyz = split3(p.p);
        data.push({ type: 'scatter3d', mode: 'lines', x: xyz[0], y: xyz[1], z: xyz[2], name: 'programmed path', meta: -1,
                    line: { color: '#9a9a9a', width: 2 }, hoverinfo: 'skip' });
        programmedDone = true;
      }
      if (p) {
        var m = split3(p.m), c = Array.from(p.e, function (v) { return v > 0 ? Math.log10(v) : cmin; });
        var text = Array.from(p.e, function (v, i) { return r.label + '<br>t = ' + p.t[i].toFixed(4) + ' s<br>TCP error ' + Number(v).toPrecision(4) + ' mm'; });
        data.push({ type: 'scatter3d', mode: 'lines', x: m[0], y: m[1], z: m[2], name: r.label + ' TCP path', meta: k,
                    line: { color: c, colorscale: 'Viridis', cmin: cmin, cmax: cmax, width: 5, showscale: !colorbarDone,
                            colorbar: { title: { text: 'TCP error [mm]' }, tickvals: ticks, ticktext: ticks.map(function (d) { return String(Math.pow(10, d).toPrecision(1)); }), len: 0.6 } },
                    text: text, hoverinfo: 'text' });
        colorbarDone = true;
      }
    });
    runs.forEach(function (r, k) {
      var ev = r.events;
      var p = pathData[k];
      if (!ev.length || !p) return;
      var x = [], y = [], z = [], text = [];
      ev.forEach(function (e) {
        var i = nearest(e.time_s, p.t); if (i < 0) return;
        x.push(p.m[3 * i]); y.push(p.m[3 * i + 1]); z.push(p.m[3 * i + 2]);
        text.push(r.label + ': ' + e.kind + (e.joint ? ' axis ' + e.joint : '') + ' at t = ' + Number(e.time_s).toFixed(4) + ' s' + (e.detail ? '<br>' + e.detail : ''));
      });
      data.push({ type: 'scatter3d', mode: 'markers', x: x, y: y, z: z, meta: k, name: r.label + ' events',
                  marker: { symbol: 'x', size: 6, color: '#d62728' }, text: text, hoverinfo: 'text' });
    });
    runs.forEach(function (r, k) {
      if (!armData[k]) return;
      sceneTraces.arm.push(data.length);
      var xyz = armSolids(Array.from(armData[k].q.subarray(0, 6))), f = armFaces(), per = solids.i.length;
      var colours = solids.links.map(function (s, l) { return shade(r.colour, l % 2 ? 0.35 : -0.15); });
      data.push({ type: 'mesh3d', x: xyz[0], y: xyz[1], z: xyz[2], i: f.i, j: f.j, k: f.k, meta: k, name: r.label + ' arm',
                  facecolor: f.i.map(function (_, n) { return colours[Math.floor(n / per)]; }), flatshading: true,
                  lighting: { ambient: 0.6, diffuse: 0.6, specular: 0.1 }, opacity: 1, hoverinfo: 'name' });
    });
    runs.forEach(function (r, k) {
      if (!pathData[k]) return;
      sceneTraces.cursor.push(data.length);
      data.push({ type: 'scatter3d', mode: 'markers', x: [pathData[k].m[0]], y: [pathData[k].m[1]], z: [pathData[k].m[2]], meta: k,
                  name: r.label + ' TCP now', marker: { size: 5, color: r.colour, line: { color: '#000', width: 1 } }, hoverinfo: 'name' });
    });
    R.sceneTraces = sceneTraces;
    if (!data.length) { scene.textContent = 'No arm poses or TCP path in these results.'; return Promise.resolve(); }
    var layout = { margin: { l: 0, r: 0, t: 0, b: 0 }, showlegend: false, uirevision: 'keep',
                   scene: { aspectmode: 'data', xaxis: { title: { text: 'x [m]' } }, yaxis: { title: { text: 'y [m]' } }, zaxis: { title: { text: 'z [m]' } },
                            camera: { eye: { x: 1.6, y: -1.6, z: 0.9 } } } };
    var before = performance.now();
    var made = Plotly.newPlot(scene, data, layout, { responsive: true, displaylogo: false });
    R.marks['newPlot scene'] = performance.now() - before;
    return made;
  }
  var scenePending = false;
  function updateScene() {                 // R.sceneDone: settles once the scene shows R.time
    if (scenePending || !scene.data || R.time === null) return;
    scenePending = true;
    R.sceneDone = new Promise(function (done) { requestAnimationFrame(function () {
      scenePending = false;
      var xs = [], ys = [], zs = [], idx = [];
      var t = R.time, a = 0, c = 0;
      runs.forEach(function (r, k) {
        if (armData[k]) {
          var i = nearest(t, armData[k].t), xyz = armSolids(Array.from(armData[k].q.subarray(6 * i, 6 * i + 6)));
          idx.push(sceneTraces.arm[a++]); xs.push(xyz[0]); ys.push(xyz[1]); zs.push(xyz[2]);
        }
      });
      runs.forEach(function (r, k) {
        if (pathData[k]) {
          var i = nearest(t, pathData[k].t), m = pathData[k].m;
          idx.push(sceneTraces.cursor[c++]); xs.push([m[3 * i]]); ys.push([m[3 * i + 1]]); zs.push([m[3 * i + 2]]);
        }
      });
      done(idx.length ? Plotly.restyle(scene, { x: xs, y: ys, z: zs }, idx) : null);
    }); });
  }

  // ---------------------------------------------------------------- readout
  var readout = document.getElementById('readout');
  var readPanels = D.panels.filter(function (p) { return runs.some(function (r) { return r.series[p.key]; }); });
  function buildReadout() {
    var h = el('tr'); h.appendChild(el('th', {}, 'at the cursor'));
    readPanels.forEach(function (p) { h.appendChild(el('th', {}, p.key === 'tcp_error' ? 'TCP error [mm]' : p.ylabel.replace(' (log scale)', '') + (p.joints.length ? ' (axis shown)' : ''))); });
    readout.appendChild(h);
    runs.forEach(function (r, k) {
      var tr = el('tr', { 'data-run': r.label }); var name = el('td', {}, r.label); name.style.borderLeft = '4px solid ' + r.colour; tr.appendChild(name);
      readPanels.forEach(function (p) { tr.appendChild(el('td', { 'class': 'readout', 'data-run': r.label, 'data-panel': p.key }, '-')); });
      readout.appendChild(tr);
    });
  }
  var readToken = 0;
  function updateReadout(quick) {          // quick: from the overview where its sample is the cursor's (no decoding)
    var t = R.time, token = ++readToken, jobs = [];
    readout.querySelectorAll('td.readout').forEach(function (td) {
      var k = runs.findIndex(function (r) { return r.label === td.getAttribute('data-run'); });
      var r = runs[k], key = td.getAttribute('data-panel');
      var plot = plots.find(function (p) { return p.panel.key === key; });
      var joint = plot && plot.joint ? plot.joint : 1;
      var c = (r.series[key] || []).find(function (c) { return !c.joint || c.joint === joint; });
      if (!c) { td.textContent = '-'; return; }
      var tx = r.times[c.source], tr0 = plot.traces.find(function (q) { return q.curve === c; });
      var io = quick ? nearest(t, tr0.ox) : -1;
      var fromOverview = quick && io >= 0 && tr0.ox[io] === t && (!c.full || c.full.dtype === c.oy.dtype);
      var data = fromOverview ? Promise.resolve([null, null])
        : Promise.all([full(tx.full), c.full ? full(c.full) : Promise.resolve(null)]);
      jobs.push(data.then(function (xy) {
        if (token !== readToken) return;
        var x = xy[0], y = xy[1], exact = !!y || fromOverview;
        if (!y) { x = tr0.ox; y = tr0.oy; }
        var i = nearest(t, x);
        if (i < 0 || t < x[0] - 1e-9 || t > x[x.length - 1] + 1e-9) { td.textContent = 'not recorded'; td.setAttribute('data-value', 'null'); return; }
        td.textContent = fmt(y[i]) + (exact ? '' : ' (decimated)');
        td.setAttribute('data-value', String(y[i]));
        td.setAttribute('data-time', String(x[i]));
        td.title = (c.joint ? 'axis ' + c.joint + ', ' : '') + 'sample at t = ' + x[i] + ' s';
      }));
    });
    return Promise.all(jobs);
  }

  // ---------------------------------------------------------------- time
  function setTime(t, quick) {
    t = Math.min(tMax, Math.max(tMin, Number(t)));
    R.time = t;
    slider.value = t;
    document.getElementById('time-now').textContent = 't = ' + t.toFixed(4) + ' s';
    placeCursors();
    updateScene();
    R.readoutDone = updateReadout(quick);
    return R.readoutDone;
  }
  R.setTime = setTime;
  R.setRange = function (a, b) { return setRange([a, b], null); };
  slider.addEventListener('input', function () { stop(); setTime(Number(slider.value)); });
  var playing = false, last = null, playButton = document.getElementById('play');
  function frame(now) {
    if (!playing) return;
    var speed = Number(document.getElementById('speed').value);
    if (last !== null) {
      var t = R.time + (now - last) / 1000 * speed;
      if (t >= tMax) { setTime(tMax); stop(); return; }
      setTime(t);
    }
    last = now;
    requestAnimationFrame(frame);
  }
  function stop() { playing = false; last = null; playButton.innerHTML = '&#9654; play'; }
  playButton.addEventListener('click', function () {
    if (playing) { stop(); return; }
    if (R.time >= tMax) setTime(tMin);
    playing = true; playButton.innerHTML = '&#10074;&#10074; pause'; requestAnimationFrame(frame);
  });
  document.addEventListener('keydown', function (e) { if (e.code === 'Space' && e.target === document.body) { e.preventDefault(); playButton.click(); } });

  // ---------------------------------------------------------------- toggles and events
  function buildToggles() {
    var box = document.getElementById('toggles');
    runs.forEach(function (r, k) {
      var label = el('label', { 'data-run': r.label });
      var cb = el('input', { type: 'checkbox', 'data-run': r.label }); cb.checked = true;
      cb.addEventListener('change', function () { setEnabled(k, cb.checked); });
      var sw = el('span', { 'class': 'swatch' }); sw.style.background = r.colour;
      label.append(cb, sw, document.createTextNode(r.label + ' '), badge(r.status));
      label.title = r.title;
      box.appendChild(label);
    });
  }
  function setEnabled(k, on) {
    enabled[k] = on;
    plots.forEach(function (p) { Plotly.update(p.div, { visible: p.traces.map(function (tr) { return visibleFor(p, tr); }) }, { shapes: limitShapes(p) }); resolution(p); });
    if (scene.data) {
      var idx = [], vis = [];
      scene.data.forEach(function (tr, i) { if (tr.meta >= 0) { idx.push(i); vis.push(enabled[tr.meta]); } });
      Plotly.restyle(scene, { visible: vis }, idx);
    }
    readout.querySelectorAll('tr[data-run]').forEach(function (tr) { tr.style.opacity = enabled[runs.findIndex(function (r) { return r.label === tr.getAttribute('data-run'); })] ? 1 : 0.35; });
  }
  R.setEnabled = setEnabled;
  R.enabled = enabled;
  function buildEvents() {
    var box = document.getElementById('events'), all = [];
    runs.forEach(function (r) { r.events.forEach(function (e) { all.push([r, e]); }); });
    if (!all.length) { box.appendChild(el('p', {}, 'No limit, fault or bus events recorded.')); return; }
    all.sort(function (a, b) { return a[1].time_s - b[1].time_s; });
    var table = el('table'), h = el('tr');
    ['time [s]', 'run', 'kind', 'axis', 'value', 'limit', 'unit', 'reaction', 'detail'].forEach(function (c) { h.appendChild(el('th', {}, c)); });
    table.appendChild(h);
    all.slice(0, 500).forEach(function (re) {
      var e = re[1], tr = el('tr');
      [Number(e.time_s).toFixed(4), re[0].label, e.kind, e.joint, e.value, e.limit, e.unit, e.reaction, e.detail].forEach(function (v) { tr.appendChild(el('td', {}, fmt(v))); });
      tr.addEventListener('click', function () { setTime(e.time_s); });
      table.appendChild(tr);
    });
    box.appendChild(table);
    // events as markers on the plots' timeline
    var evx = all.map(function (re) { return re[1].time_s; }), evy = all.map(function (re) { return re[0].label; });
    var div = el('div', { 'class': 'plot', id: 'plot-events' }); div.style.height = (90 + 22 * runs.length) + 'px';
    var pbox = el('div', { 'class': 'panel', 'data-panel': 'events' }); pbox.appendChild(div);
    var cursor = el('div', { 'class': 'cursor' }); pbox.appendChild(cursor);
    document.getElementById('plots').appendChild(pbox);
    var p = { panel: { key: 'events', title: 'events' }, traces: [], joint: 0, box: pbox, div: div, cursor: cursor, res: el('span') };
    plots.push(p);
    return Plotly.newPlot(div, [{ type: 'scatter', mode: 'markers', x: evx, y: evy, marker: { symbol: 'x', color: '#d62728', size: 9 },
      text: all.map(function (re) { return re[1].kind + (re[1].joint ? ' axis ' + re[1].joint : '') + (re[1].detail ? ': ' + re[1].detail : ''); }), hoverinfo: 'text+x' }],
      { title: { text: 'Limit, fault and bus events', font: { size: 13 }, x: 0.01, xanchor: 'left' }, margin: { l: 140, r: 12, t: 30, b: 30 },
        xaxis: { range: [tMin, tMax] }, yaxis: { type: 'category' }, showlegend: false }, { responsive: true, displaylogo: false }).then(function () {
        div.on('plotly_relayout', function (ev) { onRelayout(p, ev); });
        div.on('plotly_click', function (ev) { if (ev.points && ev.points.length) setTime(Number(ev.points[0].x)); });
      });
  }

  // ---------------------------------------------------------------- start
  window.addEventListener('resize', function () { setTimeout(placeCursors, 100); });
  try {
    buildSummary();
    buildToggles();
    buildReadout();
  } catch (e) { R.errors.push(String(e)); console.error(e); }
  mark('summary');
  // the plots, the timeline and the readout first (interactive: R.ready), then the 3D scene (R.sceneReady):
  // a WebGL scene takes seconds in a software renderer (headless browsers) and must not hold the rest up
  scene.textContent = 'building the 3D view ...';
  Promise.all([buildPlots().then(function () { mark('plots'); }), Promise.resolve(buildEvents())]).then(function () {
    return setTime(tMin, true);
  }).then(function () {
    mark('readout');
    R.ready = true;
    R.readyMs = performance.now() - t0;
    R.readyAt = performance.now();      // ms since the navigation started
    document.body.setAttribute('data-ready', '1');
    return new Promise(function (resolve) { setTimeout(resolve, 0); });
  }).then(function () {
    scene.textContent = '';
    setTimeout(function () {              // decode the readout's full-resolution curves while the user looks
      plots.forEach(function (p) { p.traces.forEach(function (tr) { if (tr.curve.full && (!tr.joint || tr.joint === 1)) { full(runs[tr.run].times[tr.curve.source].full); full(tr.curve.full); } }); });
    }, 0);
    return buildScene();
  }).then(function () {
    mark('scene');
    updateScene();
    R.sceneReady = true;
    R.sceneReadyAt = performance.now();
  }).catch(function (e) { R.errors.push(String(e && e.stack || e)); console.error(e); });
})();
