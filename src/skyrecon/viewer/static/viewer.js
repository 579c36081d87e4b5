// skyrecon 3D viewer page (MIT, part of skyrecon). Plain script: runs from file:// with no network.
// Reads the JSON in #meta and the base64 typed arrays in the #b-* elements (written by
// skyrecon.viewer.html), draws them with three.js and OrbitControls, and signals readiness by
// setting document.title to 'skyrecon-view: ready' after the first frame. Coordinates are world
// metres minus meta.offset (z up).
(function () {
  'use strict';
  const meta = JSON.parse(document.getElementById('meta').textContent);

  function bytes(id) {
    const el = document.getElementById(id);
    if (!el) return new Uint8Array(0);
    const s = atob(el.textContent.trim());
    el.textContent = '';
    const out = new Uint8Array(s.length);
    for (let i = 0; i < s.length; i++) out[i] = s.charCodeAt(i);
    return out;
  }
  function f32(id) {
    const b = bytes(id);
    return new Float32Array(b.buffer, 0, b.length >> 2);
  }

  // Height ramp: blue (low) -> cyan -> green -> yellow -> red (high).
  const RAMP = [[48, 18, 200], [20, 170, 230], [40, 200, 90], [240, 220, 40], [230, 50, 40]];
  function ramp(t, out, o) {
    t = Math.min(1, Math.max(0, t)) * (RAMP.length - 1);
    const i = Math.min(RAMP.length - 2, Math.floor(t));
    const f = t - i;
    for (let k = 0; k < 3; k++) out[o + k] = RAMP[i][k] + f * (RAMP[i + 1][k] - RAMP[i][k]);
  }
  function heightColors(pos) {
    const n = pos.length / 3;
    const out = new Uint8Array(n * 3);
    const lo = meta.z_range[0];
    const span = Math.max(meta.z_range[1] - lo, 1e-9);
    for (let i = 0; i < n; i++) ramp((pos[3 * i + 2] - lo) / span, out, 3 * i);
    return out;
  }

  const W = () => window.innerWidth;
  const H = () => window.innerHeight;
  const renderer = new THREE.WebGLRenderer({ antialias: false });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setSize(W(), H());
  renderer.setClearColor(0x15171c, 1);
  document.body.appendChild(renderer.domElement);

  const scene = new THREE.Scene();
  const radius = Math.max(meta.radius, 1e-6);
  const camera = new THREE.PerspectiveCamera(50, W() / H(), radius / 2000, radius * 50);
  camera.up.set(0, 0, 1);
  scene.add(new THREE.AmbientLight(0xffffff, 0.65));
  const sun = new THREE.DirectionalLight(0xffffff, 0.55);
  sun.position.set(0.4, 0.6, 1.0);
  scene.add(sun);

  // Points
  let points = null;
  let rgbColors = null;
  let zColors = null;
  let mode = meta.color_mode;
  const ptsPos = f32('b-points');
  if (ptsPos.length) {
    const geo = new THREE.BufferGeometry();
    geo.setAttribute('position', new THREE.BufferAttribute(ptsPos, 3));
    rgbColors = meta.has_rgb ? bytes('b-colors') : null;
    zColors = heightColors(ptsPos);
    if (!rgbColors) mode = 'height';
    geo.setAttribute('color', new THREE.BufferAttribute(mode === 'rgb' ? rgbColors : zColors, 3, true));
    const mat = new THREE.PointsMaterial({ size: meta.point_size, sizeAttenuation: true, vertexColors: true });
    points = new THREE.Points(geo, mat);
    scene.add(points);
  }

  // Occupied voxels: instanced cubes, or points the size of a voxel when there are very many.
  const voxPos = f32('b-voxels');
  let voxels = null;
  if (voxPos.length) {
    const n = voxPos.length / 3;
    const cols = heightColors(voxPos);
    if (n <= meta.max_cubes) {
      const s = meta.voxel_size * 0.96;
      const mesh = new THREE.InstancedMesh(new THREE.BoxGeometry(s, s, s), new THREE.MeshLambertMaterial(), n);
      const m = new THREE.Matrix4();
      const c = new THREE.Color();
      for (let i = 0; i < n; i++) {
        m.makeTranslation(voxPos[3 * i], voxPos[3 * i + 1], voxPos[3 * i + 2]);
        mesh.setMatrixAt(i, m);
        mesh.setColorAt(i, c.setRGB(cols[3 * i] / 255, cols[3 * i + 1] / 255, cols[3 * i + 2] / 255));
      }
      voxels = mesh;
    } else {
      const geo = new THREE.BufferGeometry();
      geo.setAttribute('position', new THREE.BufferAttribute(voxPos, 3));
      geo.setAttribute('color', new THREE.BufferAttribute(cols, 3, true));
      voxels = new THREE.Points(geo, new THREE.PointsMaterial({ size: meta.voxel_size, vertexColors: true }));
    }
    scene.add(voxels);
  }

  // Camera frusta
  const camPos = f32('b-cameras');
  if (camPos.length) {
    const geo = new THREE.BufferGeometry();
    geo.setAttribute('position', new THREE.BufferAttribute(camPos, 3));
    scene.add(new THREE.LineSegments(geo, new THREE.LineBasicMaterial({ color: 0xff5a5a })));
  }

  // Paths: a line and a dot per waypoint.
  const pathPos = f32('b-paths');
  let start = 0;
  for (const p of meta.paths) {
    const arr = pathPos.subarray(3 * start, 3 * (start + p.count));
    start += p.count;
    const geo = new THREE.BufferGeometry();
    geo.setAttribute('position', new THREE.BufferAttribute(arr, 3));
    const color = new THREE.Color(p.color[0] / 255, p.color[1] / 255, p.color[2] / 255);
    scene.add(new THREE.Line(geo, new THREE.LineBasicMaterial({ color: color, depthTest: false })));
    const dots = new THREE.Points(geo, new THREE.PointsMaterial({ color: color, size: 4, sizeAttenuation: false, depthTest: false }));
    scene.add(dots);
  }

  // View: look at the centre of the data from the south-west, above.
  const controls = new THREE.OrbitControls(camera, renderer.domElement);
  function resetView() {
    const dir = new THREE.Vector3(-0.55, -0.75, 0.6).normalize();
    const dist = radius / Math.sin((camera.fov * Math.PI) / 360) * 1.05;
    camera.position.copy(dir.multiplyScalar(dist));
    controls.target.set(0, 0, 0);
    controls.update();
  }
  resetView();

  // Overlay
  const fmt = (x) => Number(x).toLocaleString('en-US');
  const info = document.getElementById('info');
  function updateInfo() {
    const lines = ['<b>' + escapeHtml(meta.title) + '</b>'];
    if (meta.counts.points || meta.counts.total_points) {
      let s = 'points: ' + fmt(meta.counts.points);
      if (meta.counts.total_points > meta.counts.points) s += ' of ' + fmt(meta.counts.total_points) + ' (subsampled)';
      lines.push(s);
    }
    if (meta.counts.total_voxels) {
      let s = 'occupied voxels: ' + fmt(meta.counts.voxels) + ' (' + meta.voxel_size + ' m)';
      if (meta.counts.total_voxels > meta.counts.voxels) s += ' of ' + fmt(meta.counts.total_voxels);
      lines.push(s);
    }
    if (meta.counts.cameras) lines.push('cameras: ' + fmt(meta.counts.cameras));
    for (const p of meta.paths) {
      lines.push('<i class="sw" style="background: rgb(' + p.color.join(',') + ')"></i>' + escapeHtml(p.name) +
        ': ' + fmt(p.count) + ' points, ' + p.length_m.toFixed(1) + ' m');
    }
    lines.push('offset: ' + meta.offset.map((v) => v.toFixed(3)).join(', ') + ' m');
    if (points) lines.push('colour: ' + mode + (rgbColors ? ' <button id="toggle">c: toggle</button>' : ''));
    lines.push('<small>drag: orbit, right-drag: pan, wheel: zoom, +/-: point size, r: reset view</small>');
    info.innerHTML = lines.join('<br>');
    const b = document.getElementById('toggle');
    if (b) b.onclick = toggleColors;
  }
  function escapeHtml(s) {
    return String(s).replace(/[&<>"']/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' })[c]);
  }
  function toggleColors() {
    if (!points || !rgbColors) return;
    mode = mode === 'rgb' ? 'height' : 'rgb';
    points.geometry.setAttribute('color', new THREE.BufferAttribute(mode === 'rgb' ? rgbColors : zColors, 3, true));
    updateInfo();
    render();
  }
  updateInfo();

  function render() {
    renderer.render(scene, camera);
  }
  controls.addEventListener('change', render);
  window.addEventListener('resize', () => {
    camera.aspect = W() / H();
    camera.updateProjectionMatrix();
    renderer.setSize(W(), H());
    render();
  });
  window.addEventListener('keydown', (e) => {
    if (e.key === 'c') toggleColors();
    else if ((e.key === '+' || e.key === '=') && points) { points.material.size *= 1.4; render(); }
    else if (e.key === '-' && points) { points.material.size /= 1.4; render(); }
    else if (e.key === 'r') { resetView(); render(); }
  });

  render();
  requestAnimationFrame(() => {
    render();
    requestAnimationFrame(() => {
      document.body.dataset.ready = '1';
      if (!window.skyreconErrors || window.skyreconErrors.length === 0) document.title = 'skyrecon-view: ready';
    });
  });
})();
