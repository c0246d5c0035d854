// The three.js scene: bones (opaque, posed per frame), muscle surfaces (translucent, one colour
// each), fibres (line segments coloured by strain or force) and action lines. Object names are
// "bone:<name>", "muscle:<name>", "fibres:<name>", "action_line:<name>"; each muscle's objects sit in
// the group "muscle_group:<name>", whose visibility the muscle list toggles.
import * as THREE from 'three';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
import type { Frame, Run } from './data';
import { colourFor, type ColourMode } from './colormap';

export interface FibreScale { lo: number; hi: number; unit: string; }

export class SceneView {
  readonly renderer: THREE.WebGLRenderer;
  readonly scene = new THREE.Scene();
  readonly camera: THREE.PerspectiveCamera;
  readonly controls: OrbitControls;
  private bones: THREE.Mesh[] = [];
  private muscleGroups: THREE.Group[] = [];
  private surfaces: (THREE.Mesh | null)[] = [];
  private fibres: THREE.LineSegments[] = [];
  private actionLines: THREE.Line[] = [];
  colourMode: ColourMode = 'strain';
  private needsRender = true;

  constructor(private container: HTMLElement, private run: Run) {
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
    this.renderer.setClearColor(0xf4f5f7);
    container.appendChild(this.renderer.domElement);
    this.camera = new THREE.PerspectiveCamera(35, 1, 0.001, 100);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.addEventListener('change', () => this.requestRender());
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8090a0, 1.6));
    const sun = new THREE.DirectionalLight(0xffffff, 1.8);
    sun.position.set(1, 2, 1.5);
    this.camera.add(sun);
    this.scene.add(this.camera);
    this.build();
    new ResizeObserver(() => this.resize()).observe(container);
    this.resize();
  }

  private build() {
    const { manifest, mesh } = this.run;
    const boneMaterial = new THREE.MeshStandardMaterial({ color: 0xe3dbc9, roughness: 0.8, metalness: 0.0 });
    manifest.bodies.forEach((body, b) => {
      const g = new THREE.BufferGeometry();
      g.setAttribute('position', new THREE.BufferAttribute(mesh.bodies[b].vertices, 3));
      g.setIndex(new THREE.BufferAttribute(mesh.bodies[b].triangles, 1));
      g.computeVertexNormals();
      const m = new THREE.Mesh(g, boneMaterial);
      m.name = `bone:${body.name}`;
      m.matrixAutoUpdate = false;
      // The default pose until a frame is shown (and for a run that wrote no frame).
      if (body.X_ground_default && body.X_ground_default.some((v) => v !== 0)) m.matrix.fromArray(body.X_ground_default);
      this.bones.push(m);
      this.scene.add(m);
    });
    const first = this.run.frames[0];
    manifest.muscles.forEach((muscle, i) => {
      const group = new THREE.Group();
      group.name = `muscle_group:${muscle.name}`;
      const colour = new THREE.Color(...muscle.color);
      const tri = mesh.muscleTriangles[i];
      const nv = first ? first.muscles[i].surface.length : 0;
      if (tri.length > 0 && nv > 0) {
        const g = new THREE.BufferGeometry();
        g.setAttribute('position', new THREE.BufferAttribute(new Float32Array(nv), 3));
        g.setIndex(new THREE.BufferAttribute(tri, 1));
        const mat = new THREE.MeshStandardMaterial({ color: colour, transparent: true, opacity: 0.45,
          depthWrite: false, side: THREE.DoubleSide, roughness: 0.6 });
        const s = new THREE.Mesh(g, mat);
        s.name = `muscle:${muscle.name}`;
        s.renderOrder = 2;
        group.add(s);
        this.surfaces.push(s);
      } else {
        this.surfaces.push(null);
      }
      const fg = new THREE.BufferGeometry();
      const f = new THREE.LineSegments(fg, new THREE.LineBasicMaterial({ vertexColors: true }));
      f.name = `fibres:${muscle.name}`;
      f.renderOrder = 1;
      group.add(f);
      this.fibres.push(f);
      const ag = new THREE.BufferGeometry();
      const a = new THREE.Line(ag, new THREE.LineBasicMaterial({ color: colour.clone().multiplyScalar(0.5) }));
      a.name = `action_line:${muscle.name}`;
      group.add(a);
      this.actionLines.push(a);
      this.muscleGroups.push(group);
      this.scene.add(group);
    });
  }

  // Initial view: the whole model at the first frame, seen from the front-side.
  // The box covers the bones at up to 9 frames spread over the run and the muscles' box over all
  // frames (manifest box_m), so the motion stays in view.
  frameModel() {
    const box = new THREE.Box3();
    const { manifest, frames } = this.run;
    if (manifest.muscles.length && manifest.box_m && frames.length > 0)
      box.expandByPoint(new THREE.Vector3(...manifest.box_m[0])).expandByPoint(new THREE.Vector3(...manifest.box_m[1]));
    const step = Math.max(1, Math.floor(frames.length / 8));
    for (let k = 0; k < frames.length; k += step) {
      this.bones.forEach((m, b) => {
        if (!m.geometry.boundingBox) m.geometry.computeBoundingBox();
        const X = new THREE.Matrix4().fromArray(frames[k].bodyMatrices[b]);
        box.union(m.geometry.boundingBox!.clone().applyMatrix4(X));
      });
    }
    if (frames.length === 0) this.scene.updateMatrixWorld(true);
    if (box.isEmpty() || frames.length === 0) box.union(new THREE.Box3().setFromObject(this.scene));
    if (box.isEmpty()) return;
    const centre = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3());
    // Distance at which the box's bounding sphere fits both the vertical and horizontal field of view.
    const radius = Math.max(size.length() / 2, 1e-3);
    const vfov = (this.camera.fov * Math.PI) / 180;
    const hfov = 2 * Math.atan(Math.tan(vfov / 2) * this.camera.aspect);
    const distance = radius / Math.sin(Math.min(vfov, hfov) / 2);
    this.camera.up.set(0, 1, 0);
    this.camera.position.copy(centre).add(new THREE.Vector3(0.8, 0.25, 1).normalize().multiplyScalar(distance));
    this.camera.near = distance / 100;
    this.camera.far = distance * 10;
    this.camera.updateProjectionMatrix();
    this.controls.target.copy(centre);
    this.controls.update();
    this.requestRender();
  }

  showFrame(frame: Frame, fibreValue: (muscle: number, fibre: number) => number, scale: FibreScale) {
    this.bones.forEach((m, b) => {
      if (frame.bodyMatrices[b]) m.matrix.fromArray(frame.bodyMatrices[b]);
      m.matrixWorldNeedsUpdate = true;
    });
    frame.muscles.forEach((mf, i) => {
      const s = this.surfaces[i];
      if (s) {
        const attr = s.geometry.getAttribute('position') as THREE.BufferAttribute;
        if (attr.array.length === mf.surface.length) {
          (attr.array as Float32Array).set(mf.surface);
          attr.needsUpdate = true;
          s.geometry.computeVertexNormals();
          s.geometry.computeBoundingSphere();
        }
      }
      // Fibres as segments, one colour per fibre.
      let segments = 0;
      for (const f of mf.fibres) segments += Math.max(0, f.length / 3 - 1);
      const pos = new Float32Array(segments * 6), col = new Float32Array(segments * 6);
      let at = 0;
      mf.fibres.forEach((f, k) => {
        const [r, g, b] = colourFor(this.colourMode, fibreValue(i, k), scale.lo, scale.hi);
        for (let p = 0; p + 1 < f.length / 3; p++) {
          for (let e = 0; e < 2; e++) {
            pos.set(f.subarray((p + e) * 3, (p + e) * 3 + 3), at);
            col[at] = r; col[at + 1] = g; col[at + 2] = b;
            at += 3;
          }
        }
      });
      const fg = this.fibres[i].geometry;
      fg.setAttribute('position', new THREE.BufferAttribute(pos, 3));
      fg.setAttribute('color', new THREE.BufferAttribute(col, 3));
      fg.computeBoundingSphere();
      const ag = this.actionLines[i].geometry;
      ag.setAttribute('position', new THREE.BufferAttribute(mf.actionLine.slice(), 3));
      ag.computeBoundingSphere();
    });
    this.requestRender();
  }

  setMuscleVisible(i: number, visible: boolean) {
    this.muscleGroups[i].visible = visible;
    this.requestRender();
  }

  setPartVisible(kind: 'bone' | 'muscle' | 'fibres' | 'action_line', visible: boolean) {
    const list: THREE.Object3D[] = kind === 'bone' ? this.bones : kind === 'muscle'
      ? this.surfaces.filter((s): s is THREE.Mesh => s !== null) : kind === 'fibres' ? this.fibres : this.actionLines;
    list.forEach((o) => (o.visible = visible));
    this.requestRender();
  }

  listObjects(): { name: string; visible: boolean; vertices: number }[] {
    const out: { name: string; visible: boolean; vertices: number }[] = [];
    this.scene.traverse((o) => {
      if (!o.name || o.name.startsWith('muscle_group:')) return;
      let visible = true;
      for (let p: THREE.Object3D | null = o; p; p = p.parent) visible &&= p.visible;
      const g = (o as THREE.Mesh).geometry as THREE.BufferGeometry | undefined;
      const pos = g?.getAttribute('position');
      out.push({ name: o.name, visible, vertices: pos ? pos.count : 0 });
    });
    return out;
  }

  requestRender() { this.needsRender = true; }

  renderIfNeeded() {
    if (!this.needsRender) return;
    this.needsRender = false;
    this.renderer.render(this.scene, this.camera);
  }

  private resize() {
    const w = Math.max(1, this.container.clientWidth), h = Math.max(1, this.container.clientHeight);
    this.renderer.setSize(w, h);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.requestRender();
  }
}
