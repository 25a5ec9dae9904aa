// The 3-D scene of a skill or an execution, drawn with three.js (vendored in static/vendor/, served with the page):
// the work piece, the robot (the iiwa URDF and STL meshes Foxglove gets, from the API), the path taught (dashed)
// and the path executed (solid), compliant-frame triads along the path (x red, y green, z blue: into the surface),
// a grid on the floor (z = 0, the robot's base) with its cell size and coordinates in metres, and orbit controls
// (drag: rotate; right-drag or shift-drag: pan; wheel: zoom). World frame, z up, metres.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { STLLoader } from "three/addons/loaders/STLLoader.js";
import { CSS2DRenderer, CSS2DObject } from "three/addons/renderers/CSS2DRenderer.js";
import { Line2 } from "three/addons/lines/Line2.js";
import { LineGeometry } from "three/addons/lines/LineGeometry.js";
import { LineMaterial } from "three/addons/lines/LineMaterial.js";

THREE.Object3D.DEFAULT_UP.set(0, 0, 1);

export const STYLE = {
  taught: { color: 0x1d2330, width: 2.5, dashed: true },     // the path taught (the controller's reference): dashed
  executed: { color: 0xff6d00, width: 3.5, dashed: false },  // the tool point as it went: solid orange
  workPiece: 0xc8a46e,
};
const AXIS_COLORS = [0xd32f2f, 0x2e7d32, 0x1565c0];
const ROBOT_URDF = "/dashboard/robot/model.urdf";
const MESH_PREFIX = "package://kuka_iiwa/meshes/";
const MESH_URL = "/dashboard/robot/meshes/";

// ------------------------------------------------------------------------------------------------ the robot (URDF)

const downloads = new Map();   // URL -> promise of its text or geometry: one download per page, shared by the scenes

function once(url, load) {
  // A failed download is forgotten (the API restarting, say), so that the next call tries again.
  if (!downloads.has(url)) downloads.set(url, load(url).catch((error) => { downloads.delete(url); throw error; }));
  return downloads.get(url);
}

function urdfPose(node) {
  // A URDF <origin xyz rpy> as a matrix: rpy are fixed-axis roll, pitch, yaw (R = Rz Ry Rx).
  const origin = node?.querySelector(":scope > origin");
  const xyz = (origin?.getAttribute("xyz") || "0 0 0").trim().split(/\s+/).map(Number);
  const rpy = (origin?.getAttribute("rpy") || "0 0 0").trim().split(/\s+/).map(Number);
  return new THREE.Matrix4().compose(new THREE.Vector3(...xyz),
    new THREE.Quaternion().setFromEuler(new THREE.Euler(rpy[0], rpy[1], rpy[2], "ZYX")), new THREE.Vector3(1, 1, 1));
}

function urdfColor(visual, named) {
  const material = visual.querySelector("material");
  const rgba = material?.querySelector("color")?.getAttribute("rgba") || named[material?.getAttribute("name")];
  const [r, g, b] = (rgba || "0.7 0.7 0.7 1").trim().split(/\s+/).map(Number);
  return new THREE.Color(r, g, b);
}

async function visualObject(visual, named) {
  const geometry = visual.querySelector("geometry > *");
  const material = new THREE.MeshStandardMaterial({ color: urdfColor(visual, named), metalness: 0.1, roughness: 0.6 });
  let mesh;
  if (geometry.tagName === "mesh") {
    const file = geometry.getAttribute("filename");
    const url = MESH_URL + file.slice(MESH_PREFIX.length);
    mesh = new THREE.Mesh(await once(url, (u) => new STLLoader().loadAsync(u)), material);
  } else if (geometry.tagName === "cylinder") {
    const [r, l] = ["radius", "length"].map((k) => Number(geometry.getAttribute(k)));
    mesh = new THREE.Mesh(new THREE.CylinderGeometry(r, r, l, 24).rotateX(Math.PI / 2), material);   // along z
  } else if (geometry.tagName === "sphere") {
    mesh = new THREE.Mesh(new THREE.SphereGeometry(Number(geometry.getAttribute("radius")), 24, 16), material);
  } else if (geometry.tagName === "box") {
    mesh = new THREE.Mesh(new THREE.BoxGeometry(...geometry.getAttribute("size").trim().split(/\s+/).map(Number)), material);
  } else return null;
  mesh.matrixAutoUpdate = false;
  mesh.matrix.copy(urdfPose(visual));
  return mesh;
}

async function parsedRobot() {
  // {root, joints: [{name, axis, motion}]}: links as groups, each revolute joint a fixed frame (its origin) holding a
  // group turned about its axis that holds the child link.
  const text = await once(ROBOT_URDF, async (u) => {
    const response = await fetch(u);
    if (!response.ok) throw new Error(`${u}: ${response.status}`);
    return response.text();
  });
  const xml = new DOMParser().parseFromString(text, "application/xml");
  const robot = xml.documentElement;
  const named = Object.fromEntries([...robot.querySelectorAll(":scope > material")].map(
    (m) => [m.getAttribute("name"), m.querySelector("color")?.getAttribute("rgba")]));
  const links = {};
  await Promise.all([...robot.querySelectorAll(":scope > link")].map(async (link) => {
    const group = new THREE.Group();
    group.name = link.getAttribute("name");
    for (const visual of link.querySelectorAll(":scope > visual")) {
      const object = await visualObject(visual, named);
      if (object) group.add(object);
    }
    links[group.name] = group;
  }));
  const children = new Set();
  const joints = [];
  for (const joint of robot.querySelectorAll(":scope > joint")) {
    const parent = links[joint.querySelector("parent").getAttribute("link")];
    const child = links[joint.querySelector("child").getAttribute("link")];
    const frame = new THREE.Group();
    frame.matrixAutoUpdate = false;
    frame.matrix.copy(urdfPose(joint));
    const motion = new THREE.Group();
    frame.add(motion); motion.add(child); parent.add(frame);
    children.add(child.name);
    if (joint.getAttribute("type") !== "fixed") {
      const axis = (joint.querySelector("axis")?.getAttribute("xyz") || "0 0 1").trim().split(/\s+/).map(Number);
      joints.push({ name: joint.getAttribute("name"), axis: new THREE.Vector3(...axis).normalize(), motion });
    }
  }
  const root = Object.values(links).find((link) => !children.has(link.name));
  return { root, joints };
}

// ------------------------------------------------------------------------------------------------ the scene

function niceStep(span) {
  // A grid cell of 1, 2 or 5 x 10^k m giving about 8-20 cells over span.
  const raw = span / 12;
  const base = 10 ** Math.floor(Math.log10(raw));
  return [1, 2, 5, 10].map((m) => m * base).find((s) => s >= raw);
}

const metres = (v, step) => `${v.toFixed(Math.max(0, -Math.floor(Math.log10(step) + 1e-9)))} m`;

export class Scene3D {
  constructor(container, { height = 440 } = {}) {
    this.container = container;
    container.classList.add("scene3d");
    container.style.height = `${height}px`;
    const width = container.clientWidth || 600;
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio || 1);
    this.renderer.setSize(width, height);
    this.renderer.setClearColor(0xf7f8fa);
    this.labels = new CSS2DRenderer();
    this.labels.setSize(width, height);
    this.labels.domElement.className = "scene3d-labels";
    this.note = document.createElement("div");
    this.note.className = "scene3d-note";
    const views = document.createElement("div");
    views.className = "scene3d-views";
    for (const [name, close] of [["whole cell", false], ["the path", true]]) {
      const button = document.createElement("button");
      button.type = "button";
      button.textContent = name;
      button.addEventListener("click", () => { this.close = close; this.fit(true); });
      views.append(button);
    }
    container.append(this.renderer.domElement, this.labels.domElement, this.note, views);
    this.scene = new THREE.Scene();
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x667788, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(1, -1.5, 2.5);
    this.scene.add(sun);
    this.camera = new THREE.PerspectiveCamera(40, width / height, 0.005, 50);
    this.camera.position.set(1.6, -1.4, 1.1);
    this.controls = new OrbitControls(this.camera, this.labels.domElement);
    this.controls.addEventListener("change", () => this.render());
    this.userMoved = false;   // the user turned the camera: a live view no longer frames it again by itself
    this.close = false;       // framing the path alone (its button), else the whole cell
    this.controls.addEventListener("start", () => { this.userMoved = true; });
    this.layers = {};   // name -> Object3D, replaced by set*()
    this.fitted = false;
    this.robot = null;
    this.robotReady = null;   // the arm's link tree, built once per scene (the downloads are shared)
    this.pendingJoints = null;   // the last angles asked for: a pose asked while the arm loads is applied after
    new ResizeObserver(() => this.resize()).observe(container);
  }

  resize() {
    const width = this.container.clientWidth, height = this.container.clientHeight;
    if (!width || !height) return;
    this.renderer.setSize(width, height);
    this.labels.setSize(width, height);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
    for (const material of this.lineMaterials()) material.resolution.set(width, height);
    this.render();
  }

  lineMaterials() {
    const found = [];
    this.scene.traverse((o) => { if (o.material?.isLineMaterial) found.push(o.material); });
    return found;
  }

  render() {
    if (this.frame) return;
    this.frame = requestAnimationFrame(() => {
      this.frame = null;
      this.renderer.render(this.scene, this.camera);
      this.labels.render(this.scene, this.camera);
    });
  }

  replace(name, object) {
    const old = this.layers[name];
    if (old) {
      this.scene.remove(old);
      old.traverse((o) => { o.geometry?.dispose(); if (o.element) o.element.remove(); });
    }
    this.layers[name] = object;
    if (object) this.scene.add(object);
    this.render();
  }

  // The arm at joint angles (rad, the URDF's movable joints in order); null hides it.
  // Never rejects: a robot that could not be loaded (the API restarting) is asked for again at the next call.
  async setRobot(joints) {
    this.pendingJoints = joints;
    if (!joints) { if (this.robot) this.robot.root.visible = false; this.render(); return; }
    this.robotReady ??= parsedRobot().then((robot) => { this.scene.add(robot.root); return robot; });
    try {
      this.robot = await this.robotReady;
    } catch (error) {
      this.robotReady = null;
      this.container.dataset.robotError = error.message;
      return;
    }
    this.robot.root.visible = true;
    this.pendingJoints.forEach((angle, k) => this.robot.joints[k]?.motion.quaternion.setFromAxisAngle(this.robot.joints[k].axis, angle));
    this.container.dataset.robot = "1";
    this.render();
  }

  // A path [[x, y, z] m, ...] in one of STYLE's styles (taught, executed).
  setPath(name, points, style) {
    const kept = points.filter((p) => p && p.every(Number.isFinite));
    if (kept.length < 2) { this.replace(name, null); return; }
    const geometry = new LineGeometry();
    geometry.setPositions(kept.flat());
    const material = new LineMaterial({ color: style.color, linewidth: style.width, dashed: style.dashed,
      dashSize: 0.01, gapSize: 0.006, resolution: new THREE.Vector2(this.container.clientWidth, this.container.clientHeight) });
    const line = new Line2(geometry, material);
    if (style.dashed) {
      // The taught path drawn over everything: where the tool follows it exactly, its dashes lie on the executed
      // path and the gaps between them show it.
      line.computeLineDistances();
      Object.assign(material, { depthTest: false, transparent: true });   // drawn after the (translucent) work piece
      line.renderOrder = 2;
    }
    this.replace(name, line);
    this.container.dataset[name] = String(kept.length);
  }

  // Compliant frames [{origin: [x, y, z], axes: [x, y, z] (unit vectors, world)}], each drawn as a triad of
  // `length` m.
  setTriads(triads, length = 0.03) {
    const group = new THREE.Group();
    for (const t of triads) {
      const origin = new THREE.Vector3(...t.origin);
      t.axes.forEach((axis, j) => {
        group.add(new THREE.ArrowHelper(new THREE.Vector3(...axis), origin, length, AXIS_COLORS[j], 0.25 * length, 0.12 * length));
      });
    }
    // Over everything, as the taught path: a CF sits at the tool point, on (or in) the surface it presses.
    group.traverse((o) => { if (o.material) { Object.assign(o.material, { depthTest: false, transparent: true }); o.renderOrder = 3; } });
    this.replace("triads", group);
    this.container.dataset.triads = String(triads.length);
  }

  // The work piece: meshes [{name, vertices: [[x, y, z] m], triangles: [[i, j, k]]}] (world frame).
  setWorkPiece(meshes) {
    const group = new THREE.Group();
    for (const m of meshes || []) {
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute("position", new THREE.Float32BufferAttribute(m.vertices.flat(), 3));
      geometry.setIndex(m.triangles.flat());
      geometry.computeVertexNormals();
      const solid = new THREE.Mesh(geometry, new THREE.MeshStandardMaterial({
        color: STYLE.workPiece, roughness: 0.85, transparent: true, opacity: 0.8, side: THREE.DoubleSide, flatShading: true }));
      solid.name = m.name;
      group.add(solid, new THREE.LineSegments(new THREE.EdgesGeometry(geometry, 30), new THREE.LineBasicMaterial({ color: 0x8a6a3a })));
    }
    this.replace("workPiece", group);
    this.container.dataset.workPiece = String((meshes || []).length);
  }

  // The floor grid at z = 0 under everything drawn, its cell size and coordinates labelled in metres, and the world
  // axes at the origin (the robot's base).
  setGrid(box) {
    const span = Math.max(box.max.x - box.min.x, box.max.y - box.min.y, 0.4);
    const step = niceStep(span * 1.3);
    const lo = [Math.floor(Math.min(box.min.x, 0) / step) * step, Math.floor(Math.min(box.min.y, 0) / step) * step];
    const hi = [Math.ceil(Math.max(box.max.x, 0) / step) * step, Math.ceil(Math.max(box.max.y, 0) / step) * step];
    const group = new THREE.Group();
    const vertices = [];
    for (let x = lo[0]; x <= hi[0] + 1e-9; x += step) vertices.push(x, lo[1], 0, x, hi[1], 0);
    for (let y = lo[1]; y <= hi[1] + 1e-9; y += step) vertices.push(lo[0], y, 0, hi[0], y, 0);
    const grid = new THREE.BufferGeometry();
    grid.setAttribute("position", new THREE.Float32BufferAttribute(vertices, 3));
    group.add(new THREE.LineSegments(grid, new THREE.LineBasicMaterial({ color: 0xc5cad3 })));
    const label = (text, x, y, z, cls = "") => {
      const div = document.createElement("div");
      div.className = `scene3d-label ${cls}`;
      div.textContent = text;
      const object = new CSS2DObject(div);
      object.position.set(x, y, z);
      group.add(object);
    };
    const every = Math.max(1, Math.round((hi[0] - lo[0]) / step / 6));
    for (let k = 0, x = lo[0]; x <= hi[0] + 1e-9; x += step, k++) if (k % every === 0) label(`x ${metres(x, step)}`, x, lo[1] - 0.3 * step, 0);
    for (let k = 0, y = lo[1]; y <= hi[1] + 1e-9; y += step, k++) if (k % every === 0) label(`y ${metres(y, step)}`, hi[0] + 0.3 * step, y, 0);
    this.note.textContent = `grid on the floor (z = 0, the robot's base): ${metres(step, step)} cells; axes x red, y green, z blue`;
    const axes = new THREE.AxesHelper(step);
    group.add(axes);
    ["x", "y", "z"].forEach((name, j) => label(name, ...[0, 1, 2].map((i) => (i === j ? 1.15 * step : 0)), `axis-${name}`));
    this.replace("grid", group);
    this.container.dataset.gridStep = String(step);
  }

  // Fit the camera and the grid to what is drawn (once, unless `again`: a live view keeps the user's camera).
  fit(again = false) {
    const box = new THREE.Box3();
    for (const name of ["taught", "executed", "workPiece", "triads"]) if (this.layers[name]) box.expandByObject(this.layers[name]);
    if (box.isEmpty()) return;
    this.setGrid(box);
    if (this.fitted && !again) return;
    this.fitted = true;
    // The robot too when it is drawn: its base at the origin, its arm up to about a metre above it.
    const reach = box.clone();
    if (this.close) reach.copy(new THREE.Box3().setFromObject(this.layers.taught || this.layers.executed || this.layers.triads));
    else if (this.robot?.root.visible || this.pendingJoints) reach.expandByPoint(new THREE.Vector3(0, 0, 0)).expandByPoint(new THREE.Vector3(0, 0, 1.0));
    const centre = this.close ? reach.getCenter(new THREE.Vector3()) : box.getCenter(new THREE.Vector3());
    const size = reach.getSize(new THREE.Vector3()).length();
    const look = reach.getCenter(new THREE.Vector3()).lerp(centre, 0.75);   // the work, with the arm around it
    this.controls.target.copy(look);
    this.camera.position.copy(look).add(new THREE.Vector3(0.5, -1.0, 0.5).normalize().multiplyScalar(1.05 * Math.max(size, this.close ? 0.08 : 0.4)));
    this.camera.near = size / 200; this.camera.far = size * 20;
    this.camera.updateProjectionMatrix();
    this.controls.update();
    this.render();
  }
}
