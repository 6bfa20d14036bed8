// The report's 3D viewer: cameras, sparse and dense points, the mesh; three.js + OrbitControls.
// Data comes from <script id="viewer-data" type="application/json"> (see recon/report/viewer.py).
(function () {
  "use strict";
  const box = document.getElementById("viewer");
  const source = document.getElementById("viewer-data");
  if (!box || !source) return;
  const data = JSON.parse(source.textContent);
  const status = document.getElementById("viewer-status");

  function bytes(b64) {
    const text = atob(b64);
    const out = new Uint8Array(text.length);
    for (let i = 0; i < text.length; i++) out[i] = text.charCodeAt(i);
    return out;
  }
  const floats = (b64) => new Float32Array(bytes(b64).buffer);

  let renderer;
  try {
    renderer = new THREE.WebGLRenderer({ antialias: true });
  } catch (err) {
    status.textContent = "The 3D viewer needs WebGL, which this browser does not offer.";
    box.dataset.state = "no-webgl";
    return;
  }
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  box.querySelector(".canvas-holder").appendChild(renderer.domElement);

  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0x1d2430);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x404050, 2.2));
  const sun = new THREE.DirectionalLight(0xffffff, 1.2);
  scene.add(sun);

  const up = new THREE.Vector3().fromArray(data.up).normalize();
  const r = data.radius;
  const camera = new THREE.PerspectiveCamera(50, 1, r / 1000, r * 100);
  camera.up.copy(up);
  // start looking from the side and somewhat above, along a direction perpendicular to up
  const side = new THREE.Vector3(1, 0, 0);
  if (Math.abs(side.dot(up)) > 0.9) side.set(0, 1, 0);
  side.sub(up.clone().multiplyScalar(side.dot(up))).normalize();
  camera.position.copy(side.multiplyScalar(2.6 * r).add(up.clone().multiplyScalar(1.3 * r)));
  const controls = new THREE.OrbitControls(camera, renderer.domElement);
  controls.target.set(0, 0, 0);
  controls.update();

  function render() {
    sun.position.copy(camera.position);
    renderer.render(scene, camera);
  }
  const holder = box.querySelector(".canvas-holder");
  function resize() {
    const w = holder.clientWidth, h = Math.max(320, Math.round(w * 0.55));
    renderer.setSize(w, h, false);  // the stylesheet sizes the canvas to its holder
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
    render();
  }
  controls.addEventListener("change", render);
  new ResizeObserver(resize).observe(holder);

  const objects = {};
  let pending = 0;
  for (const layer of data.layers) {
    if (layer.kind === "points" || layer.kind === "lines") {
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute("position", new THREE.BufferAttribute(floats(layer.positions), 3));
      let object;
      if (layer.kind === "points") {
        geometry.setAttribute("color", new THREE.BufferAttribute(bytes(layer.colors), 3, true));
        object = new THREE.Points(geometry, new THREE.PointsMaterial({
          size: layer.size, sizeAttenuation: false, vertexColors: true }));
      } else {
        object = new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ color: layer.color }));
      }
      objects[layer.id] = object;
      scene.add(object);
    } else if (layer.kind === "mesh") {
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute("position", new THREE.BufferAttribute(floats(layer.positions), 3));
      geometry.setIndex(new THREE.BufferAttribute(new Uint32Array(bytes(layer.indices).buffer), 1));
      if (layer.colors) geometry.setAttribute("color", new THREE.BufferAttribute(bytes(layer.colors), 3, true));
      geometry.computeVertexNormals();
      const material = new THREE.MeshStandardMaterial({
        color: layer.colors ? 0xffffff : 0xb8b8b8, vertexColors: !!layer.colors,
        side: THREE.DoubleSide, roughness: 0.9 });
      objects[layer.id] = new THREE.Mesh(geometry, material);
      scene.add(objects[layer.id]);
    } else if (layer.kind === "glb") {
      pending++;
      const group = new THREE.Group();
      group.matrixAutoUpdate = false;  // glTF's Y-up frame to the viewer's (recon's world less the origin)
      group.matrix.fromArray(layer.matrix);
      objects[layer.id] = group;
      scene.add(group);
      new THREE.GLTFLoader().parse(bytes(layer.data).buffer, "", (gltf) => {
        group.add(gltf.scene);
        pending--;
        ready();
      }, (err) => {
        status.textContent = "Could not read the textured model: " + err;
        pending--;
        ready();
      });
    }
  }

  const toggles = box.querySelector(".layers");
  for (const layer of data.layers) {
    const label = document.createElement("label");
    const input = document.createElement("input");
    input.type = "checkbox";
    input.checked = true;
    input.addEventListener("change", () => { objects[layer.id].visible = input.checked; render(); });
    label.append(input, " " + layer.label);
    toggles.appendChild(label);
  }

  function ready() {
    if (pending > 0) return;
    resize();
    box.dataset.state = "ready";
  }
  ready();
})();
